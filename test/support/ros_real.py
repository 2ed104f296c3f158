"""Find a real ROS 2 Jazzy and build this package into a throw-away colcon workspace.

The peer is never part of this repository. A user sources ROS (``setup.bash``) before
``make test``, or points ``LPV_SYSID_ROS_SETUP`` at a ``setup.bash``; ``/opt/ros/jazzy`` is
tried last (the Ubuntu install location). The test process itself keeps its own
interpreter: every ROS command runs in a ``bash`` that sources the setup, with ROS's
``python3`` (which must have this package's pip requirements, requirements-ros.txt).

:func:`find_ros` says why ROS is unusable (tests skip with that line);
:func:`build_package` runs ``colcon build`` of the checkout once per test session into a
temporary workspace (the source tree is copied, so the build leaves nothing in it);
:class:`RosEnv` runs commands and background processes (own process group, so a test
can send SIGINT the way a terminal does) on an isolated ``ROS_DOMAIN_ID``, localhost only.
"""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ENV = "LPV_SYSID_ROS_SETUP"
DEFAULT_SETUP = Path("/opt/ros/jazzy/setup.bash")
#: what the real-ROS tests use: rclpy, launch, the message packages of the package's topics
#: and the ``ros2`` verbs the tests call (a partial build without ``ros2 launch`` is unusable,
#: not a failure), and the package's pip requirements in ROS's own ``python3``
PROBE = (
    "import rclpy, launch, launch_ros, std_srvs.srv, nav_msgs.msg, sensor_msgs.msg, "
    "geometry_msgs.msg, diagnostic_msgs.msg, rcl_interfaces.msg; "
    "import ros2launch, ros2topic, ros2param, ros2node, ros2service, ros2run, ros2pkg; "
    "import numpy, scipy, yaml, pymavlink, rosbags"
)


def _setup_candidates() -> list[Path]:
    out = []
    if os.environ.get(ENV):
        out.append(Path(os.environ[ENV]))
    prefix = os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)[0]
    if prefix:
        out.append(Path(prefix) / "setup.bash")
    out.append(DEFAULT_SETUP)
    return out


def find_ros() -> tuple[Path | None, str]:
    """(setup.bash, "") when a ROS 2 with rclpy and this package's deps is usable."""
    for setup in _setup_candidates():
        if not setup.is_file():
            continue
        r = subprocess.run(
            [
                "bash",
                "-c",
                f"source {shlex.quote(str(setup))} >/dev/null 2>&1 "
                f"&& python3 -c {shlex.quote(PROBE)}",
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
        if r.returncode == 0:
            return setup, ""
        last = (r.stderr.strip().splitlines() or ["?"])[-1]
        return (
            None,
            f"ROS 2 at {setup} unusable for lpv_sysid ({last}); "
            "pip install -r requirements-ros.txt",
        )
    return None, (
        f"real ROS 2 not available: source a Jazzy setup.bash or set {ENV} "
        f"(tried {', '.join(str(p) for p in _setup_candidates())})"
    )


#: as ROS's domain_coordinator (launch_testing): a ROS_DOMAIN_ID d in 1..100 is taken while
#: TCP port PORT_BASE + d is bound, so concurrent sessions never share a domain
PORT_BASE = 32768


class DomainId:
    """A reserved ROS_DOMAIN_ID (``.value``) until :meth:`release`; ``start`` spreads
    the search so that parallel reservations in one process rarely probe the same ids."""

    def __init__(self, start: int = 0):
        import socket

        for k in range(100):
            d = (start + k) % 100 + 1
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            try:
                s.bind(("", PORT_BASE + d))
            except OSError:
                s.close()
                continue
            self.value, self._socket = d, s
            return
        raise RuntimeError("no free ROS_DOMAIN_ID in 1..100")

    def release(self) -> None:
        self._socket.close()


class RosEnv:
    """Commands in a sourced ROS environment, isolated on one domain id, localhost only.

    ``ROS_PYTHON_CHECK_FIELDS=1``: message fields are type-checked on assignment, as the
    in-repo stand-in does (Jazzy's default skips the checks; a wrong type then fails only
    at publish with "bad argument type", or is converted silently)."""

    def __init__(self, setup: Path, workspace: Path, domain_id: int):
        self.setup = Path(setup)
        self.workspace = Path(workspace)
        self.domain_id = int(domain_id)

    def _script(self, cmd: str) -> str:
        ws = self.workspace / "install" / "setup.bash"
        return (
            f"source {shlex.quote(str(self.setup))} >/dev/null && "
            f"source {shlex.quote(str(ws))} >/dev/null && "
            f"export ROS_DOMAIN_ID={self.domain_id} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "
            f"RMW_IMPLEMENTATION=${{RMW_IMPLEMENTATION:-rmw_cyclonedds_cpp}} "
            f"ROS_PYTHON_CHECK_FIELDS=1 && {cmd}"
        )

    def run(
        self,
        cmd: str,
        timeout: float = 60.0,
        cwd: str | os.PathLike | None = None,
        check: bool = False,
    ) -> subprocess.CompletedProcess:
        r = subprocess.run(
            ["bash", "-c", self._script(cmd)],
            capture_output=True,
            text=True,
            timeout=timeout,
            cwd=cwd,
        )
        if check and r.returncode != 0:
            raise AssertionError(f"{cmd!r} exited {r.returncode}:\n{r.stdout}\n{r.stderr}")
        return r

    def popen(self, cmd: str, log: Path, cwd: str | os.PathLike | None = None) -> "Proc":
        f = open(log, "wb")
        p = subprocess.Popen(
            ["bash", "-c", self._script("exec " + cmd)],
            stdout=f,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            cwd=cwd,
            start_new_session=True,
        )
        return Proc(p, Path(log), f)


class Proc:
    """A background ROS process in its own process group (``exec``: the pid is the process)."""

    def __init__(self, popen: subprocess.Popen, log: Path, fh):
        self.p, self.log_path, self._fh = popen, log, fh

    def log(self) -> str:
        if not self._fh.closed:
            self._fh.flush()
        return self.log_path.read_text(errors="replace")

    def wait_for(self, text: str, timeout: float, unless: str | None = None) -> bool:
        """Whether ``text`` appears in the log within ``timeout`` s; False at once when
        ``unless`` appears first (e.g. an abort: no point waiting for the rest)."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            log = self.log()
            if text in log:
                return True
            if unless is not None and unless in log:
                return False
            if self.p.poll() is not None:
                return text in self.log()
            time.sleep(0.2)
        return False

    def sigint(self, group: bool = False) -> None:
        if self.p.poll() is None:
            if group:
                os.killpg(self.p.pid, signal.SIGINT)
            else:
                self.p.send_signal(signal.SIGINT)

    @property
    def pid(self) -> int:
        return self.p.pid

    def wait(self, timeout: float) -> int:
        """Exit status (subprocess.TimeoutExpired if still running after ``timeout``)."""
        rc = self.p.wait(timeout=timeout)
        self._fh.close()
        return rc

    def kill(self) -> None:
        if self.p.poll() is None:
            os.killpg(self.p.pid, signal.SIGKILL)
            self.p.wait(timeout=10)
        self._fh.close()


def build_package(setup: Path, base: Path | None = None) -> Path:
    """colcon-build a copy of this checkout; returns the workspace (``install/`` inside)."""
    ws = Path(base or tempfile.mkdtemp(prefix="lpv_ros_ws_"))
    src = ws / "src" / "lpv_sysid"
    if src.exists():
        shutil.rmtree(src)
    ignore = shutil.ignore_patterns(
        ".venv",
        ".git",
        "__pycache__",
        "*.egg-info",
        "build",
        "install",
        "log",
        "demo_out",
        ".pytest_cache",
    )
    shutil.copytree(ROOT, src, ignore=ignore)
    r = subprocess.run(
        [
            "bash",
            "-c",
            f"source {shlex.quote(str(setup))} >/dev/null && "
            f"colcon build --packages-select lpv_sysid",
        ],
        cwd=ws,
        capture_output=True,
        text=True,
        timeout=600,
    )
    if r.returncode != 0:
        raise RuntimeError(f"colcon build failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    return ws
