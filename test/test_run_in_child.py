"""``parallel.run_in_child`` (the chain's synthesis step): Ctrl-C reaches the caller while the
work in the child holds SIGINT for itself, as the native LMI solvers do (SCS ends its solve as
"failed", Clarabel finishes; seen on PX4 SITL: two SIGINTs during the chain's synthesis were
lost and the chain went on to phase 2).

Oracle: a terminal's Ctrl-C is SIGINT to the whole foreground process group. The caller must
end with KeyboardInterrupt, the child must be gone, and the child's work must not complete."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def swallow_sigint_and_work(marker: str, seconds: float) -> str:
    """A stand-in for a native solver: SIGINT ignored, work that takes ``seconds``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    Path(marker).write_text(str(os.getpid()))
    time.sleep(seconds)
    Path(marker + ".done").write_text("finished")
    return "finished"


def test_result_and_exception_come_back():
    from lpv_sysid.parallel import run_in_child

    assert run_in_child(divmod, 7, 2) == (3, 1)
    with pytest.raises(ZeroDivisionError):
        run_in_child(divmod, 1, 0)


def test_ctrl_c_ends_the_caller_and_the_child_while_the_child_holds_sigint(tmp_path):
    marker = tmp_path / "child.pid"
    script = (
        "import sys; sys.path[:0] = [%r, %r]\n"
        "from lpv_sysid.parallel import run_in_child\n"
        "from test_run_in_child import swallow_sigint_and_work\n"
        "try:\n"
        "    print(run_in_child(swallow_sigint_and_work, %r, 60.0), flush=True)\n"
        "except KeyboardInterrupt:\n"
        "    print('KeyboardInterrupt', flush=True)\n"
        "    raise SystemExit(130)\n"
    ) % (str(ROOT), str(ROOT / "test"), str(marker))
    proc = subprocess.Popen(
        [sys.executable, "-c", script],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a terminal's foreground job
    )
    try:
        for _ in range(600):  # the child has started its work (bounded: 120 s)
            if marker.exists() and marker.read_text():
                break
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.2)
        else:
            pytest.fail("the child never started")
        child_pid = int(marker.read_text())
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=45)  # the work itself would take 60 s
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130 and out.strip() == "KeyboardInterrupt", (out, err)
    assert not (tmp_path / "child.pid.done").exists()
    with pytest.raises(ProcessLookupError):
        os.kill(child_pid, 0)  # reaped by the caller: no such process
