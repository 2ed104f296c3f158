"""Protocol tests: the bridge core against the simulated PX4 vehicle over UDP on 127.0.0.1.

Both ends are driven in lock-step by one simulated clock (``step(t)`` / ``poll(t)``) while
every message really travels through loopback UDP sockets, so a 15 s flight takes well
under a second of wall time and the outcome does not depend on machine load.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys

import numpy as np
import pytest

from lpv_sysid.mavlink import codec, px4
from lpv_sysid.mavlink.bridge import BridgeConfig, BridgeCore
from lpv_sysid.mavlink.link import LinkConfig, free_udp_port
from lpv_sysid.mavlink.offboard import OffboardConfig, State, StatusEvent
from lpv_sysid.mavlink.preflight import NOGO, judge, run_checks, verdict
from lpv_sysid.mavlink.telemetry import RotorSample, StateSample
from lpv_sysid.sim.px4_vehicle import SimVehicle, SimVehicleConfig

DT = 0.004
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class UdpRelay:
    """Forwards datagrams vehicle <-> bridge; ``cut = True`` drops everything (link cut)."""

    def __init__(self, bridge_port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        self.bridge = ("127.0.0.1", bridge_port)
        self.vehicle = None
        self.cut = False
        self.dropped = 0
        self.drop_to_vehicle = None  # optional predicate(datagram) -> drop it

    def pump(self) -> None:
        for _ in range(10000):
            try:
                data, addr = self.sock.recvfrom(65535)
            except BlockingIOError:
                return
            if self.cut:
                self.dropped += 1
                continue
            if addr == self.bridge:
                if self.drop_to_vehicle is not None and self.drop_to_vehicle(data):
                    self.dropped += 1
                    continue
                if self.vehicle is not None:
                    self.sock.sendto(data, self.vehicle)
            else:
                self.vehicle = addr
                self.sock.sendto(data, self.bridge)

    def close(self) -> None:
        self.sock.close()


class Flight:
    """Bridge + vehicle (+ optional relay) on one simulated clock."""

    def __init__(
        self,
        offboard: OffboardConfig,
        vehicle_params: dict | None = None,
        relay: bool = False,
        command: str = "velocity",
        link_timeout: float = 1.5,
        duplicate_acks: bool = False,
    ) -> None:
        port = free_udp_port()
        self.relay = UdpRelay(port) if relay else None
        veh_port = self.relay.port if relay else port
        self.veh = SimVehicle(
            SimVehicleConfig(
                url=f"udpout:127.0.0.1:{veh_port}",
                params=vehicle_params or {},
                duplicate_acks=duplicate_acks,
            )
        )
        self.bridge = BridgeCore(
            BridgeConfig(
                link=LinkConfig(url=f"udpin:127.0.0.1:{port}", link_timeout=link_timeout),
                offboard=offboard,
                command=command,
            )
        )
        self.t = 0.0
        self.events: list = []
        self.samples: list = []
        self.truth: list = []
        self.last_ref_t = -1.0
        self.bridge.open(0.0)
        self.veh.open()

    def tick(self) -> None:
        self.t += DT
        self.veh.step(self.t)
        if self.relay is not None:
            self.relay.pump()
        out = self.bridge.poll(self.t)
        self.events += out.events
        for s in out.samples:
            self.samples.append(s)
            self.truth.append((s, self.veh.x.copy()))

    def run_until(self, t_end: float, reference=None) -> None:
        n = 0
        while self.t < t_end - 1e-9:
            n += 1
            assert n < 100000
            if reference is not None:
                r = reference(self.t)
                if r is not None and int(round(self.t / DT)) % 5 == 0:  # 50 Hz reference
                    self.bridge.on_velocity_reference(self.t, r, 0.0)
                    self.last_ref_t = self.t
            self.tick()

    def transitions(self) -> list[tuple[str, str]]:
        return [
            (e.previous, e.state)
            for e in self.events
            if isinstance(e, StatusEvent) and e.previous != e.state
        ]

    def t_of(self, state: str) -> float:
        return next(
            e.t
            for e in self.events
            if isinstance(e, StatusEvent) and e.state == state and e.previous != e.state
        )

    def close(self) -> None:
        self.bridge.close()
        self.veh.close()
        if self.relay is not None:
            self.relay.close()


@pytest.fixture
def flights():
    made: list[Flight] = []

    def make(*a, **k) -> Flight:
        f = Flight(*a, **k)
        made.append(f)
        return f

    yield make
    for f in made:
        f.close()


def _takeoff_then(profile):
    def ref(t):
        if t < 0.3:
            return None
        if t < 5.0:
            return (0.0, 0.0, -1.0)  # climb (NED down < 0)
        return profile(t)

    return ref


def test_phase1_flight_prestream_offboard_arm_track_abort_handback(flights):
    f = flights(
        OffboardConfig(arm=True, handback_mode="HOLD", setpoint_rate_hz=20.0), duplicate_acks=True
    )
    amp, freq = 0.5, 0.2

    def profile(t):
        if t < 9.0:
            return (1.0, 0.0, 0.0)  # 4 s step to 1 m/s
        return (1.0 + amp * math.sin(2 * math.pi * freq * (t - 9.0)), 0.0, 0.0)

    ref = _takeoff_then(profile)
    f.run_until(0.5, ref)
    f.events += f.bridge.start(f.t)
    f.run_until(9.0, ref)
    # steady state of the 1 m/s step (integral action: no steady error), via telemetry
    st = [s for s in f.samples if isinstance(s, StateSample) and 8.5 <= s.t <= 9.0]
    assert len(st) > 20
    assert abs(np.mean([s.v_body[0] for s in st]) - 1.0) < 0.05
    assert max(abs(s.v_body[2]) for s in st) < 0.1
    f.run_until(19.0, ref)
    sin_part = [s for s in f.samples if isinstance(s, StateSample) and 10.0 <= s.t <= 19.0]
    tt = np.array([s.t - 9.0 for s in sin_part])
    vu = np.array([s.v_body[0] for s in sin_part])
    # least-squares fit v = c + a sin(wt) + b cos(wt): gain and phase of the tracking loop
    w = 2 * math.pi * freq
    coef = np.linalg.lstsq(
        np.c_[np.ones_like(tt), np.sin(w * tt), np.cos(w * tt)], vu, rcond=None
    )[0]
    gain = math.hypot(coef[1], coef[2]) / amp
    lag = -math.degrees(math.atan2(coef[2], coef[1]))
    assert 0.6 < gain < 1.15 and 0.0 < lag < 60.0, (gain, lag)
    assert abs(coef[0] - 1.0) < 0.1
    rms = float(np.sqrt(np.mean(np.square(vu - np.array([ref(s.t)[0] for s in sin_part])))))
    assert rms < 0.8 * amp / math.sqrt(2)  # below the error of just holding 1 m/s
    assert f.bridge.machine.vehicle_mode == px4.OFFBOARD  # from the vehicle HEARTBEAT
    assert f.bridge.machine.armed
    n_sp = f.veh.setpoints_received
    f.events += f.bridge.abort(f.t, "test abort")
    f.run_until(21.5, None)
    assert f.transitions() == [
        ("IDLE", "PRESTREAM"),
        ("PRESTREAM", "SWITCHING"),
        ("SWITCHING", "ARMING"),
        ("ARMING", "OFFBOARD_ACTIVE"),
        ("OFFBOARD_ACTIVE", "HANDBACK"),
        ("HANDBACK", "DONE"),
    ]
    assert f.t_of("SWITCHING") - f.t_of("PRESTREAM") > 1.0  # > 1 s pre-stream
    assert f.bridge.machine.vehicle_mode == px4.HOLD and f.veh.mode == px4.HOLD
    assert (
        f.bridge.machine.confirmed_mode == px4.HOLD
        and "hand-back confirmed: vehicle in HOLD" in f.bridge.machine.reason
    )
    # until HOLD was confirmed the bridge kept streaming the neutral setpoint (zero velocity),
    # at most at the setpoint rate; after DONE nothing more is sent
    t_abort, t_done = f.t_of("HANDBACK"), f.t_of("DONE")
    assert 0 < f.veh.setpoints_received - n_sp <= 20.0 * (t_done - t_abort) + 2
    np.testing.assert_array_equal(f.veh.setpoint.v_ned, np.zeros(3))
    n_done = f.veh.setpoints_received
    f.run_until(23.0, None)
    assert f.veh.setpoints_received == n_done  # stream stopped
    assert [m for _, m, _ in f.veh.mode_log][:2] == ["OFFBOARD", "HOLD"]
    # decode path against the simulator's truth (float32 telemetry)
    pairs = [
        (s, x) for s, x in f.truth if isinstance(s, StateSample) and s.t > 6.0 and s.skew == 0.0
    ]
    assert len(pairs) > 100
    dv = max(float(np.max(np.abs(s.v_body - x[6:9]))) for s, x in pairs)
    de = max(float(np.max(np.abs(s.euler - x[3:6]))) for s, x in pairs)
    assert dv < 1e-4 and de < 1e-5
    rot = [(s, x) for s, x in f.truth if isinstance(s, RotorSample) and s.t > 6.0]
    assert (
        rot
        and max(float(np.max(np.abs(s.omega - x[12:16]))) for s, x in rot)
        <= 0.5 * 2 * math.pi / 60 + 1e-9
    )
    assert f.bridge.link.stats.bad_data == 0 and f.bridge.link.stats.seq_lost == 0


def test_link_cut_vehicle_failsafe_and_bridge_reports_loss(flights):
    # COM_DISARM_LAND -1: the vehicle stays armed in LAND after touching down (an auto-disarm
    # would end the failsafe and show the user's OFFBOARD again, test_sim_vehicle_px4)
    f = flights(
        OffboardConfig(arm=True, handback_mode="HOLD"),
        vehicle_params={"COM_OBL_RC_ACT": 4, "COM_DISARM_LAND": -1.0},
        relay=True,
        link_timeout=1.5,
    )
    ref = _takeoff_then(lambda t: (0.5, 0.0, 0.0))
    f.run_until(0.5, ref)
    f.events += f.bridge.start(f.t)
    f.run_until(7.0, ref)
    assert f.bridge.state == State.OFFBOARD_ACTIVE
    f.relay.cut = True
    t_cut = f.t
    t_last_sp = f.veh.setpoint.t  # last setpoint that got through
    t_last_hb = f.bridge.link.last_heartbeat_t
    f.run_until(10.0, ref)
    # vehicle: offboard loss after COM_OF_LOSS_T = 1 s -> COM_OBL_RC_ACT = 4 (Land)
    lost = [(t, m, r) for t, m, r in f.veh.mode_log if m == "LAND"]
    assert lost, f.veh.mode_log
    assert 1.0 <= lost[0][0] - t_last_sp <= 1.0 + 2 * DT
    assert "COM_OF_LOSS_T" in lost[0][2]
    # bridge: link lost after link_timeout without HEARTBEAT (heartbeats are 1 Hz)
    ev = [e for e in f.events if getattr(e, "kind", "") == "link_lost"]
    assert len(ev) == 1 and 1.5 < ev[0].t - t_last_hb <= 1.5 + 2 * DT
    hb = [
        e
        for e in f.events
        if isinstance(e, StatusEvent) and e.state == "HANDBACK" and e.previous != e.state
    ]
    assert len(hb) == 1 and "link lost" in hb[0].reason and hb[0].t == ev[0].t
    # each mode of the chain (HOLD, then LAND) retried ack_timeout x max_retries, then FAILED
    # loudly: nothing was confirmed and PX4's failsafe is in charge
    assert f.bridge.state == State.HANDBACK
    f.run_until(hb[0].t + 2 * 4 * 0.5 + 0.1, ref)
    assert f.bridge.state == State.FAILED and f.bridge.machine.confirmed_mode is None
    failed = [e for e in f.events if isinstance(e, StatusEvent) and e.state == "FAILED"][-1]
    assert failed.level == "error" and failed.reason.startswith(
        "hand-back NOT confirmed: HOLD: no COMMAND_ACK"
    )
    assert "LAND: no COMMAND_ACK" in failed.reason and "PX4 failsafe in charge" in failed.reason
    n_sp = f.veh.setpoints_received
    f.relay.cut = False
    f.run_until(f.t + 2.5, ref)
    # link back: the HEARTBEAT shows LAND, the bridge ends FAILED and never resumes streaming
    assert any(getattr(e, "kind", "") == "link_up" and e.t > t_cut for e in f.events)
    assert f.bridge.machine.vehicle_mode == px4.LAND
    assert f.bridge.state == State.FAILED
    assert f.veh.setpoints_received <= n_sp + 1  # at most one in flight when the link returned
    assert f.veh.mode == px4.LAND


def test_stale_input_stops_stream_within_timeout(flights):
    cfg = OffboardConfig(arm=True, input_timeout=0.3, setpoint_rate_hz=25.0, handback_mode="LAND")
    f = flights(cfg)
    t_stop = 7.0
    ref = _takeoff_then(lambda t: (0.3, 0.0, 0.0) if t < t_stop else None)
    f.run_until(0.5, ref)
    f.events += f.bridge.start(f.t)
    f.run_until(t_stop, ref)
    assert f.bridge.state == State.OFFBOARD_ACTIVE
    f.run_until(9.0, ref)
    last_cmd = f.last_ref_t
    assert 6.9 < last_cmd < 7.01
    t_hb = f.t_of("HANDBACK")
    assert cfg.input_timeout <= t_hb - last_cmd <= cfg.input_timeout + 2 * DT
    # after the hand-back the vehicle got only the neutral setpoint (zero velocity), and none
    # once LAND was confirmed; it lands (hand-back mode LAND)
    t_end = f.t_of("FAILED")
    assert f.veh.setpoint.t <= t_end + 1e-9
    np.testing.assert_array_equal(f.veh.setpoint.v_ned, np.zeros(3))
    assert f.veh.mode == px4.LAND and f.bridge.machine.vehicle_mode == px4.LAND
    assert f.bridge.state == State.FAILED and "stale input" in f.bridge.machine.reason
    assert f.bridge.machine.confirmed_mode == px4.LAND


def test_phase2_attitude_rate_transport_reproduces_virtual_command(flights):
    f = flights(OffboardConfig(arm=True), command="attitude_rate")
    u_cmd = np.array([0.3, 0.004, -0.003, 0.02])  # below hover thrust: stays on the ground
    n = 0
    while f.t < 5.0 and n < 5000:
        n += 1
        if f.t > 0.3 and n % 5 == 0:
            f.bridge.on_actuator_command(f.t, u_cmd)
        if abs(f.t - 0.5) < DT / 2:
            f.events += f.bridge.start(f.t)
        f.tick()
    assert f.bridge.state == State.OFFBOARD_ACTIVE and f.veh.mode == px4.OFFBOARD and f.veh.armed
    # Mix u_ESC applied by the vehicle's rate loop equals the LPV command (float32 link)
    assert np.allclose(f.veh.u, u_cmd, atol=2e-6)


def test_vehicle_refuses_to_arm_in_offboard_without_setpoint_stream(flights):
    f = flights(OffboardConfig())
    f.run_until(0.5)
    acks = []
    orig = f.bridge._on_message

    def spy(msg, now, out):
        if msg.get_type() == "COMMAND_ACK":
            acks.append((msg.command, msg.result))
        orig(msg, now, out)

    f.bridge._on_message = spy
    f.bridge.link.command_long(176, 1.0, 6.0, 0.0)  # OFFBOARD without any setpoint stream
    f.run_until(0.7)
    # PX4 v1.16 (measured on SIH): disarmed, every mode change is allowed, answered twice
    assert acks == [(176, 0), (176, 0)] and f.veh.mode == px4.OFFBOARD
    f.bridge.link.command_long(400, 1.0)
    f.run_until(0.9)
    # arming is what PX4 refuses: OFFBOARD cannot run without the stream (one answer)
    assert acks[2:] == [(400, 1)] and not f.veh.armed


def test_preflight_against_sim_vehicle_go_and_nogo(flights):
    for params, expect in (({"COM_OBL_RC_ACT": 5}, True), ({"COM_OBL_RC_ACT": 7}, False)):
        f = flights(OffboardConfig(), vehicle_params=params)
        clock = {"t": 0.0}

        def sleep(dt, f=f, clock=clock):
            clock["t"] += DT
            f.veh.step(clock["t"])

        checks = run_checks(f.bridge.link, timeout=3.0, clock=lambda: clock["t"], sleep=sleep)
        names = {c.name: c for c in checks}
        assert names["firmware"].value == "1.16.0" and names["autopilot"].value == "PX4"
        assert names["COM_OF_LOSS_T"].value == "1 s"
        assert verdict(checks) is expect
        if not expect:
            assert (
                names["COM_OBL_RC_ACT"].verdict == NOGO
                and "DISARM" in names["COM_OBL_RC_ACT"].value
            )
    assert verdict(judge(None, None, {}, set())) is False


def _cli(*args: str, timeout: float = 20.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "lpv_sysid.cli", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, "PYTHONPATH": ROOT},
    )


def test_cli_preflight_against_cli_sim_vehicle():
    port = free_udp_port()
    veh = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lpv_sysid.cli",
            "sim-vehicle",
            "--udp",
            f"127.0.0.1:{port}",
            "--duration",
            "15",
            "--param",
            "COM_OBL_RC_ACT=5",
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": ROOT},
    )
    try:
        r = _cli("preflight", "--connect", f"udpin:127.0.0.1:{port}", "--timeout", "5")
    finally:
        veh.send_signal(signal.SIGINT)  # Ctrl-C: the vehicle prints its summary
        out, err = veh.communicate(timeout=15)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (
        "COM_OBL_RC_ACT" in r.stdout and "5 (HOLD)" in r.stdout and r.stdout.strip().endswith("GO")
    )
    assert veh.returncode == 0 and "final mode HOLD" in out
    # nobody there: NO-GO (1); bad input: 2 with a one-line reason
    r = _cli("preflight", "--connect", f"udpin:127.0.0.1:{free_udp_port()}", "--timeout", "0.3")
    assert r.returncode == 1 and "NO-GO" in r.stdout
    r = _cli("preflight", "--connect", "udpin:127.0.0.1:notaport")
    assert r.returncode == 2 and "port" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = _cli("preflight", "--connect", "/dev/ttyLPVSYSID_NONE", "--timeout", "0.5")
    assert r.returncode == 2 and "cannot open MAVLink connection" in r.stderr
    r = _cli("sim-vehicle", "--udp", "127.0.0.1:1", "--param", "COM_BOGUS=1", "--duration", "1")
    assert r.returncode == 2 and "COM_BOGUS" in r.stderr


def test_tcp_link_reconnects_after_vehicle_restart():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()

    def vehicle():
        v = SimVehicle(SimVehicleConfig(url=f"tcpin:127.0.0.1:{port}"))
        v.open()
        return v

    veh = vehicle()
    core = BridgeCore(
        BridgeConfig(
            link=LinkConfig(url=f"tcp:127.0.0.1:{port}", link_timeout=1.0, reconnect_period=0.5)
        )
    )
    events: list = []
    t = 0.0

    def run(t_end, v):
        nonlocal t
        n = 0
        while t < t_end and n < 5000:
            n += 1
            t += DT
            if v is not None:
                v.step(t)
            out = core.poll(t)
            events.extend(out.events)

    try:
        core.open(0.0)
        run(1.0, veh)
        assert core.link.link_up(t)
        veh.close()  # vehicle gone (reboot, cable)
        run(3.0, None)
        kinds = [e.kind for e in events if hasattr(e, "kind")]
        assert kinds[0] == "link_up" and "link_lost" in kinds
        closed = [e for e in events if getattr(e, "kind", "") == "io_error"]
        assert "peer closed" in closed[0].detail
        assert len(closed) >= 3  # reopen attempts every 0.5 s, refused
        assert not core.link.link_up(t) and core.link.conn is None
        veh = vehicle()  # back on the same port
        run(5.0, veh)
        kinds = [e.kind for e in events if hasattr(e, "kind")]
        assert kinds.count("reconnect") == 1 and kinds[-1] == "link_up"
        assert core.link.link_up(t) and core.link.stats.reconnects == 1
        assert core.telemetry.staleness(t)["attitude"] < 0.1
    finally:
        core.close()
        veh.close()


def test_lost_commands_are_retried_until_offboard(flights):
    """The first two COMMAND_LONGs (DO_SET_MODE) never reach the vehicle: the bridge retries."""
    f = flights(OffboardConfig(arm=False, ack_timeout=0.3, max_retries=3), relay=True)
    mod = codec.dialect_module()
    seen = {"n": 0}

    def drop(data: bytes) -> bool:
        msgs = mod.MAVLink(None).parse_buffer(data) or []
        if (
            any(m.get_type() == "COMMAND_LONG" and m.command == 176 for m in msgs)
            and seen["n"] < 2
        ):
            seen["n"] += 1
            return True
        return False

    f.relay.drop_to_vehicle = drop
    ref = lambda t: (0.0, 0.0, 0.0) if t > 0.3 else None  # noqa: E731
    f.run_until(0.5, ref)
    f.events += f.bridge.start(f.t)
    f.run_until(4.0, ref)
    retries = [e for e in f.events if isinstance(e, StatusEvent) and "retry" in e.reason]
    assert [e.reason.rsplit("retry ", 1)[1] for e in retries] == ["1/3", "2/3"]
    assert all("no COMMAND_ACK for command 176 within 0.3 s" in e.reason for e in retries)
    assert f.relay.dropped == 2 and f.bridge.state == State.OFFBOARD_ACTIVE
    assert f.veh.mode == px4.OFFBOARD and not f.veh.armed  # arm not configured: not armed


def test_vehicle_disarms_without_takeoff_and_serves_param_set(flights):
    f = flights(OffboardConfig(), vehicle_params={"COM_DISARM_PRFLT": 2.0})
    f.run_until(0.3)
    link = f.bridge.link
    link.send(link.codec.param_set_encode(1, 1, b"COM_OBL_RC_ACT", px4.param_to_wire(4, 6), 6))
    link.command_long(400, 1.0)  # arm on the ground
    values = []
    orig = f.bridge._on_message

    def spy(msg, now, out):
        if msg.get_type() == "PARAM_VALUE":
            values.append(
                (
                    px4.param_id_str(msg.param_id),
                    px4.param_from_wire(msg.param_value, msg.param_type),
                )
            )
        orig(msg, now, out)

    f.bridge._on_message = spy
    f.run_until(1.5)
    assert values == [("COM_OBL_RC_ACT", 4)] and f.veh.param("COM_OBL_RC_ACT") == 4
    assert f.bridge.machine.armed  # HEARTBEAT shows armed
    t_arm = f.veh.t_armed
    f.run_until(4.5)
    dis = [t for t, m, r in f.veh.mode_log if m == "DISARMED"]
    assert len(dis) == 1 and 2.0 < dis[0] - t_arm <= 2.0 + 2 * DT
    assert not f.veh.armed and not f.bridge.machine.armed


def test_phase1_flight_tracks_a_four_axis_multisine_over_udp(flights):
    """Issue 7: a phase-1 style flight over UDP with the u, v, w channels of the designed 4-axis
    multisine (signals/, seed 0 Sec. IV; the harness sends a zero yaw-rate reference)
    superposed on a 1 m/s vertex: every excited axis of the vehicle follows its reference
    channel (best-lag correlation 0.90-0.94 measured, > 0.7 required), and the mutually
    orthogonal channels do not leak into each other's axes."""
    from lpv_sysid.signals.excitation import phase1_reference, phase1_signals

    f = flights(OffboardConfig(arm=True, handback_mode="HOLD", setpoint_rate_hz=20.0))
    sig = phase1_signals(
        duration=20.0, band=(0.1, 0.8), peaks=(0.6, 0.6, 0.4, 0.3), sample_rate=50.0
    )
    core = phase1_reference((1.0, 0.0, 0.0), sig, trim=9.0)
    channels = {}

    def ref(t):
        if t < 0.3:
            return None
        if t < 5.0:
            return (0.0, 0.0, -1.0)  # climb (NED down < 0)
        v, r, _ = core.evaluate(np.array([t]))
        channels[round(t, 6)] = (v[0], r[0])
        return tuple(float(c) for c in v[0])

    f.run_until(0.5, ref)
    f.events += f.bridge.start(f.t)
    f.run_until(29.0, ref)
    assert f.bridge.machine.vehicle_mode == px4.OFFBOARD
    st = [s for s in f.samples if isinstance(s, StateSample) and 10.0 <= s.t <= 28.5]
    tt = np.array([s.t for s in st])
    v_meas = np.array([s.v_body for s in st])
    v_ref, _, _ = core.evaluate(tt)
    excitation = v_ref - np.array([1.0, 0.0, 0.0])

    def best_lag_corr(a, b):
        lags = range(0, int(1.0 / 0.02))  # up to 1 s of lag
        return max(np.corrcoef(a[: len(a) - k], b[k:])[0, 1] for k in lags)

    dt_s = np.median(np.diff(tt))
    stride = max(1, int(round(0.02 / dt_s)))
    ex, vm = excitation[::stride], v_meas[::stride]
    for axis in range(3):
        c = best_lag_corr(ex[:, axis], vm[:, axis] - vm[:, axis].mean())
        assert c > 0.7, (axis, c)
        for other in range(3):
            if other != axis:  # orthogonal channels: axis `other` barely follows channel `axis`
                assert abs(np.corrcoef(ex[:, axis], vm[:, other])[0, 1]) < 0.35, (axis, other)
    f.events += f.bridge.abort(f.t, "end of manoeuvre")
    f.run_until(31.0, None)
    assert f.bridge.machine.vehicle_mode == px4.HOLD
