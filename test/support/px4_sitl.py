"""Find and run a real PX4 SITL (SIH quadrotor) for the tests that fly the real peer.

The peer is never part of this repository: a user (or CI on a machine where it was built)
points ``PX4_SITL_DIR`` at a PX4 v1.14-v1.16 SITL build directory (``bin/px4`` and
``etc/``, a board with the SIH simulator, e.g. ``px4_sitl_default``). :func:`find_px4`
says why it is unusable (the tests skip with that line); :class:`Px4Sitl` starts one
headless instance in its own working directory with fresh parameters, waits until its
offboard MAVLink link (PX4 sends from UDP 14580+N to 127.0.0.1:14540+N) shows a PX4
HEARTBEAT, and stops it (SIGINT, then SIGKILL) on exit.

From instance 10 up PX4's ``px4-rc.mavlink`` sends the offboard link of every instance to
127.0.0.1:14549 ("use the same ports for more than 10 instances"), where several instances
would meet (measured with PX4 1.16.0: instance 14 sent to 14549; ``udpin:127.0.0.1:14554``
heard nothing). :class:`Px4Sitl` then runs the instance from a copy of the build's ``etc/``
in its working directory without that line (the peer's own tree is not changed), so every
instance N sends to 127.0.0.1:14540+N and :attr:`Px4Sitl.url` is the same for all.
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
OFFBOARD_PORT = 14540  # + instance
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


#: first instance that px4-rc.mavlink points at the shared port 14549
SHARED_FROM_INSTANCE = 10
#: the line of etc/init.d-posix/px4-rc.mavlink (PX4 v1.14-v1.16) that does it
SHARED_PORT_LINE = '[ "$px4_instance" -gt 9 ] && udp_offboard_port_remote=14549'


def own_port_build(build_dir: Path, into: Path) -> Path:
    """A build directory for an instance >= 10 that sends its offboard link to 14540+N:
    ``bin`` linked, ``etc`` copied without :data:`SHARED_PORT_LINE` (error if absent)."""
    build = into / "px4_build"
    if build.exists():
        return build
    build.mkdir(parents=True)
    (build / "bin").symlink_to((build_dir / "bin").resolve())
    shutil.copytree(build_dir / "etc", build / "etc", symlinks=True)
    rc = build / "etc" / "init.d-posix" / "px4-rc.mavlink"
    text = rc.read_text()
    if SHARED_PORT_LINE not in text and "14549" in text:
        raise RuntimeError(f"{rc}: unknown form of the instance >= 10 port line; see px4_sitl.py")
    rc.unlink()  # may be a link into the peer's tree
    rc.write_text(text.replace(SHARED_PORT_LINE, ""))
    return build


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
        """The companion-computer (offboard) link, as the bridge connects to it."""
        return f"udpin:127.0.0.1:{OFFBOARD_PORT + self.instance}"

    @property
    def gcs_url(self) -> str:
        return f"udpin:127.0.0.1:{GCS_PORT + self.instance}"

    def start(self) -> "Px4Sitl":
        for f in ("parameters.bson", "parameters_backup.bson"):
            (self.workdir / f).unlink(missing_ok=True)
        build = self.build_dir
        if self.instance >= SHARED_FROM_INSTANCE:
            build = own_port_build(self.build_dir, self.workdir)
        env = dict(os.environ, PX4_SIMULATOR="sihsim", PX4_SIM_MODEL=self.model, HEADLESS="1")
        with open(self.log_path, "wb") as log:
            self.proc = subprocess.Popen(
                [
                    str(build / "bin" / "px4"),
                    "-d",
                    "-i",
                    str(self.instance),
                    str(build / "etc"),
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
                return time.monotonic() - t0
            time.sleep(0.2)
        raise TimeoutError(f"PX4 not ready after {self.boot_timeout} s: {self.log_tail()}")

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except FileNotFoundError:
            return ""

    def own_failsafe(self) -> str | None:
        """PX4's log line when PX4 itself left the flight for a failsafe of its own estimator
        (mc_pos_control "Failsafe: blind land": no valid local position), None otherwise.
        Seen once in CI at the end of a full run: SIH's baro/compass stopped ("No valid data
        from Baro 0" after take-off) -- the SITL starved by its host, not the package's chain."""
        for line in self.log().splitlines():
            if "Failsafe: blind land" in line:
                return line.strip()
        return None

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
