"""Find and run a real PX4 SITL (SIH quadrotor) for the tests that fly the real peer.

The peer is never part of this repository: a user (or CI on a machine where it was built)
points ``PX4_SITL_DIR`` at a PX4 v1.14-v1.16 SITL build directory (``bin/px4`` and
``etc/``, a board with the SIH simulator, e.g. ``px4_sitl_default``). :func:`find_px4`
says why it is unusable (the tests skip with that line); :class:`Px4Sitl` starts one
headless instance in its own working directory with fresh parameters, waits until its
offboard MAVLink link (PX4 sends from UDP 14580+N to 127.0.0.1:14540+N) shows a PX4
HEARTBEAT, and stops it (SIGINT, then SIGKILL) on exit.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

ENV = "PX4_SITL_DIR"
OFFBOARD_PORT = 14540  # + instance (instances 0..9; see Px4Sitl.url)
#: instances >= 10: the extra onboard channel (Px4Sitl.url): PX4's port, the bridge's port
EXTRA_LOCAL_PORT = 24580  # + instance
EXTRA_REMOTE_PORT = 24540  # + instance
GCS_PORT = 14550  # + instance


def find_px4() -> tuple[Path | None, str]:
    """(build dir, "") when ``PX4_SITL_DIR`` holds a runnable SITL, else (None, reason)."""
    d = os.environ.get(ENV)
    if not d:
        return None, f"real PX4 SITL not available: set {ENV} to a PX4 SITL build directory"
    p = Path(d)
    if not (p / "bin" / "px4").is_file() or not (p / "etc").is_dir():
        return None, f"{ENV}={d} has no bin/px4 and etc/ (not a PX4 SITL build directory)"
    return p, ""


class Px4Sitl:
    """One headless SIH instance (``with Px4Sitl(instance=3) as px4: px4.url``)."""

    def __init__(
        self,
        build_dir: Path,
        instance: int = 0,
        model: str = "sihsim_quadx",
        boot_timeout: float = 60.0,
        workdir: str | None = None,
    ):
        self.build_dir = Path(build_dir)
        self.instance = int(instance)
        self.model = model
        self.boot_timeout = boot_timeout
        self._own_dir = workdir is None
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix=f"px4_i{instance}_"))
        self.proc: subprocess.Popen | None = None
        self.log_path = self.workdir / "px4.log"

    @property
    def url(self) -> str:
        """The companion-computer (offboard) link, as the bridge connects to it. PX4's
        px4-rc.mavlink sends instance N's offboard link to 14540 + N only for N <= 9; every
        instance >= 10 sends to 14549, a port shared by all of them (two autopilots heard:
        the bridge refuses), and answers only the first client it heard (``udpout`` to its
        port works for one connection: a second bridge process never got a reply). From 10 on
        :meth:`wait_ready` starts one more onboard MAVLink channel on the instance, PX4 on
        ``EXTRA_LOCAL_PORT + N`` sending to 127.0.0.1:``EXTRA_REMOTE_PORT + N``: the URL."""
        if self.instance > 9:
            return f"udpin:127.0.0.1:{EXTRA_REMOTE_PORT + self.instance}"
        return f"udpin:127.0.0.1:{OFFBOARD_PORT + self.instance}"

    @property
    def gcs_url(self) -> str:
        return f"udpin:127.0.0.1:{GCS_PORT + self.instance}"

    def start(self) -> "Px4Sitl":
        for f in ("parameters.bson", "parameters_backup.bson"):
            (self.workdir / f).unlink(missing_ok=True)
        env = dict(os.environ, PX4_SIMULATOR="sihsim", PX4_SIM_MODEL=self.model, HEADLESS="1")
        with open(self.log_path, "wb") as log:
            self.proc = subprocess.Popen(
                [
                    str(self.build_dir / "bin" / "px4"),
                    "-d",
                    "-i",
                    str(self.instance),
                    str(self.build_dir / "etc"),
                ],
                cwd=self.workdir,
                env=env,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
            )
        return self

    def wait_ready(self, predicate_text: str = "Ready for takeoff") -> float:
        """Block (bounded) until PX4 logged ``predicate_text``; returns the seconds waited."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < self.boot_timeout:
            if self.proc is not None and self.proc.poll() is not None:
                raise RuntimeError(f"PX4 exited with {self.proc.returncode}: {self.log_tail()}")
            if predicate_text in self.log():
                if self.instance > 9:
                    self._extra_channel()
                return time.monotonic() - t0
            time.sleep(0.2)
        raise TimeoutError(f"PX4 not ready after {self.boot_timeout} s: {self.log_tail()}")

    def _extra_channel(self) -> None:
        """One more onboard MAVLink channel (module ``mavlink`` through PX4's own client)."""
        n = self.instance
        r = subprocess.run(
            [
                str(self.build_dir / "bin" / "px4-mavlink"),
                "--instance",
                str(n),
                "start",
                "-u",
                str(EXTRA_LOCAL_PORT + n),
                "-r",
                "4000000",
                "-f",
                "-m",
                "onboard",
                "-o",
                str(EXTRA_REMOTE_PORT + n),
            ],
            capture_output=True,
            text=True,
            timeout=30,
        )
        if r.returncode != 0:
            raise RuntimeError(f"px4-mavlink start on instance {n}: {r.stdout}{r.stderr}")

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except FileNotFoundError:
            return ""

    def log_tail(self, n: int = 20) -> str:
        return "\n".join(self.log().splitlines()[-n:])

    def stop(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        os.killpg(self.proc.pid, signal.SIGINT)
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=10)

    def __enter__(self) -> "Px4Sitl":
        self.start()
        self.wait_ready()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
        if self._own_dir and not os.environ.get("PX4_SITL_KEEP"):
            shutil.rmtree(self.workdir, ignore_errors=True)
