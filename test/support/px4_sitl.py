"""Find and run a real PX4 SITL (SIH quadrotor) for the tests that fly the real peer.

The peer is never part of this repository: a user (or CI on a machine where it was built)
points ``PX4_SITL_DIR`` at a PX4 v1.14-v1.16 SITL build directory (``bin/px4`` and
``etc/``, a board with the SIH simulator, e.g. ``px4_sitl_default``). :func:`find_px4`
says why it is unusable (the tests skip with that line); :class:`Px4Sitl` starts one
headless instance in its own working directory with fresh parameters, waits until its
offboard MAVLink link (PX4 sends from UDP 14580+N to 127.0.0.1:14540+N) shows a PX4
HEARTBEAT, and stops it (SIGINT, then SIGKILL) on exit.

From instance 10 up PX4 sends the offboard link of every instance to 127.0.0.1:14549
(px4-rc.mavlink: "use the same ports for more than 10 instances"), where several instances
would meet: :class:`OffboardRelay` then gives instance N its own 127.0.0.1:14540+N, as for
0..9 (measured with PX4 1.16.0: instance 14 sent to 14549; ``udpin:127.0.0.1:14554`` heard
nothing).
"""

from __future__ import annotations

import os
import select
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from pathlib import Path

ENV = "PX4_SITL_DIR"
OFFBOARD_PORT = 14540  # + instance (instances 0..9; see Px4Sitl.url)
OFFBOARD_LOCAL_PORT = 14580  # + instance: PX4's own port of the offboard link
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


#: PX4's offboard link partner port of every instance >= 10 (px4-rc.mavlink)
SHARED_REMOTE_PORT = 14549
#: first instance that sends there
SHARED_FROM_INSTANCE = 10


class OffboardRelay(threading.Thread):
    """Instance N >= 10: becomes PX4's offboard partner and forwards to 127.0.0.1:14540+N.

    PX4 takes the first localhost sender on its local offboard port (14580+N) as the link's
    partner for good; the relay sends it a HEARTBEAT from its own socket (every 0.5 s until
    PX4 answers), then forwards PX4's datagrams to 127.0.0.1:14540+N from a second socket,
    and what comes back to that socket from 14540+N to PX4. A program that listens on
    ``udpin:127.0.0.1:14540+N`` sees the same link as with an instance 0..9."""

    def __init__(self, instance: int):
        super().__init__(daemon=True, name=f"px4-relay-{instance}")
        self.px4 = ("127.0.0.1", 14580 + instance)
        self.app = ("127.0.0.1", OFFBOARD_PORT + instance)
        self.to_px4 = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.to_px4.bind(("127.0.0.1", 0))
        self.to_app = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.to_app.bind(("127.0.0.1", 0))
        self.heard = threading.Event()
        self._halt = threading.Event()

    @staticmethod
    def _kick() -> bytes:
        from pymavlink.dialects.v20 import common as mav

        m = mav.MAVLink(None, srcSystem=1, srcComponent=191)
        onboard, no_autopilot = mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID
        return m.heartbeat_encode(onboard, no_autopilot, 0, 0, 0).pack(m)

    def run(self) -> None:
        kick, last = self._kick(), -1.0
        while not self._halt.is_set():
            if not self.heard.is_set() and time.monotonic() - last > 0.5:
                self.to_px4.sendto(kick, self.px4)
                last = time.monotonic()
            ready, _, _ = select.select([self.to_px4, self.to_app], [], [], 0.2)
            for sock in ready:
                try:
                    data, src = sock.recvfrom(65536)
                    if sock is self.to_px4:
                        self.heard.set()
                        self.to_app.sendto(data, self.app)
                    elif src == self.app:
                        self.to_px4.sendto(data, self.px4)
                except OSError:  # nobody on 14540+N yet, or shutting down
                    continue

    def stop(self) -> None:
        self._halt.set()
        self.join(timeout=5)
        self.to_px4.close()
        self.to_app.close()


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
        self.relay: OffboardRelay | None = None
        self.log_path = self.workdir / "px4.log"

    @property
    def url(self) -> str:
        """The companion-computer (offboard) link, as the bridge connects to it. PX4's
        px4-rc.mavlink sends instance N's offboard link to 14540 + N only for N <= 9; every
        instance >= 10 sends to 14549, a port shared by all of them (two autopilots heard:
        the bridge refuses). From 10 on the bridge sends to the instance's own local port
        14580 + N instead (``udpout``): PX4 answers the first sender on localhost."""
        if self.instance > 9:
            return f"udpout:127.0.0.1:{OFFBOARD_LOCAL_PORT + self.instance}"
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
        if self.instance >= SHARED_FROM_INSTANCE:
            self.relay = OffboardRelay(self.instance)
            self.relay.start()
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

    def log_tail(self, n: int = 20) -> str:
        return "\n".join(self.log().splitlines()[-n:])

    def stop(self) -> None:
        if self.relay is not None:
            self.relay.stop()
            self.relay = None
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
