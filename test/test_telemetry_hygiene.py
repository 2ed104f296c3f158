"""Telemetry hygiene (issue 10, finding 5) and rotor speeds without ESC telemetry (finding 4).

Messages are fabricated with pymavlink codecs whose srcSystem/srcComponent are set and
parsed back, so they carry real headers; the bridge tests send them over UDP on 127.0.0.1.
PX4 facts used: ATTITUDE_QUATERNION/ATTITUDE use time_boot_ms, ODOMETRY uses the
estimator's timestamp_sample (lags the others), ACTUATOR_OUTPUT_STATUS/SERVO_OUTPUT_RAW
copy actuator_outputs (SITL: PWM 900 disarmed, 1000..2000 us).
"""

from __future__ import annotations

import math
import socket

import numpy as np
import pytest

from lpv_sysid.io import frames
from lpv_sysid.mavlink import codec, px4
from lpv_sysid.mavlink.bridge import BridgeConfig, BridgeCore
from lpv_sysid.mavlink.link import LinkConfig, free_udp_port
from lpv_sysid.mavlink.telemetry import (
    ReceiverClock,
    RotorEstimateConfig,
    RotorSample,
    StateSample,
    TelemetryDecoder,
)

A, B, LO, HI = 12.31, 13990.0, 120.0, 1100.0  # config/quadrotor.yaml, seed 0 Eq. (8)
ROLL, ROLL_EULER_OFFSET = 0.2, 0.1  # ATTITUDE reports a different roll
ODOM_OFFSET = 100.0  # ODOMETRY reports a different position
BOOT = 10.0  # vehicle clock = receive time + BOOT


class Wire:
    """Encode with a codec of (sysid, compid), decode with ours: messages with real headers."""

    def __init__(self) -> None:
        self.tx: dict[tuple[int, int], object] = {}
        self.rx = codec.make_codec(None, 1, 191)

    def codec(self, sysid: int = 1, compid: int = 1):
        return self.tx.setdefault((sysid, compid), codec.make_codec(None, sysid, compid))

    def bytes(self, name: str, *args, sysid: int = 1, compid: int = 1, **kw) -> bytes:
        c = self.codec(sysid, compid)
        return getattr(c, f"{name}_encode")(*args, **kw).pack(c)

    def msg(self, name: str, *args, sysid: int = 1, compid: int = 1, **kw):
        (m,) = self.rx.parse_buffer(self.bytes(name, *args, sysid=sysid, compid=compid, **kw))
        assert m.get_srcSystem() == sysid and m.get_srcComponent() == compid
        return m


W = Wire()
Q_ROLL = frames.quaternion_from_euler(np.array([ROLL, 0.0, 0.0]))


def att_q(t, sysid=1, compid=1, roll_q=Q_ROLL):
    return W.msg(
        "attitude_quaternion",
        int(round((t + BOOT) * 1000)),
        *[float(v) for v in roll_q],
        0.01,
        0.02,
        0.03,
        [0.0] * 4,
        sysid=sysid,
        compid=compid,
    )


def att_euler(t, sysid=1):
    return W.msg(
        "attitude",
        int(round((t + BOOT) * 1000)),
        ROLL + ROLL_EULER_OFFSET,
        0.0,
        0.0,
        0.01,
        0.02,
        0.03,
        sysid=sysid,
    )


def lpos(t, sysid=1, compid=1, x=1.0, vx=2.0):
    return W.msg(
        "local_position_ned",
        int(round((t + BOOT) * 1000)),
        x,
        2.0,
        -3.0,
        vx,
        0.0,
        0.0,
        sysid=sysid,
        compid=compid,
    )


def odom(t, lag=0.015, sysid=1):
    # PX4: time_usec = vehicle_odometry.timestamp_sample, behind the other streams' time
    return W.msg(
        "odometry",
        int(round((t + BOOT - lag) * 1e6)),
        1,
        1,
        1.0 + ODOM_OFFSET,
        2.0,
        -3.0,
        [float(v) for v in Q_ROLL],
        2.0,
        0.0,
        0.0,
        0.01,
        0.02,
        0.03,
        [float("nan")] * 21,
        [float("nan")] * 21,
        sysid=sysid,
    )


def aos(t, pwm, sysid=1, active=16):
    out = [float(v) for v in pwm] + [900.0] * (32 - len(pwm))
    return W.msg("actuator_output_status", int(round(t * 1e6)), active, out, sysid=sysid)


def servo(t, pwm, port=0):
    raw = [int(v) for v in pwm] + [900] * (16 - len(pwm))
    return W.msg("servo_output_raw", int(round(t * 1e6)) & 0xFFFFFFFF, port, *raw)


def esc(t, rpm):
    c = W.codec()
    buf = codec.esc_status_class()(0, int(round(t * 1e6)), rpm, [16.0] * 4, [1.0] * 4).pack(c)
    (m,) = W.rx.parse_buffer(buf)
    return m


def schedule(t0, t1, rates):
    """[(t, name)] of streams at the given rates [Hz] in time order (name order at ties)."""
    ev = []
    for i, (name, rate) in enumerate(rates.items()):
        k0 = math.ceil(t0 * rate - 1e-9)
        ev += [(k / rate, i, name) for k in range(k0, int(math.floor(t1 * rate + 1e-9)) + 1)]
    return [(t, name) for t, _, name in sorted(ev)]


MAKE = {
    "ATTITUDE_QUATERNION": att_q,
    "ATTITUDE": att_euler,
    "LOCAL_POSITION_NED": lpos,
    "ODOMETRY": odom,
}


def feed(dec, events, make=MAKE):
    out = []
    for t, name in events:
        out += dec.on_message(make[name](t), t)
    return out


# ----------------------------------------------------------------- one attitude source
def test_state_at_the_rate_of_one_attitude_and_one_position_stream_without_duplicates():
    # PX4 onboard link: ATTITUDE 100 Hz and ODOMETRY 30 Hz by default, plus the requested
    # ATTITUDE_QUATERNION 100 Hz and LOCAL_POSITION_NED 50 Hz (~280 state samples/s before)
    dec = TelemetryDecoder()
    rates = {
        "ATTITUDE_QUATERNION": 100.0,
        "ATTITUDE": 100.0,
        "LOCAL_POSITION_NED": 50.0,
        "ODOMETRY": 30.0,
    }
    events = schedule(0.0, 2.0, rates)
    states = [s for s in feed(dec, events) if isinstance(s, StateSample)]
    n_q = sum(1 for _, n in events if n == "ATTITUDE_QUATERNION")
    n_p = sum(1 for _, n in events if n == "LOCAL_POSITION_NED")
    assert (n_q, n_p) == (201, 101)
    assert len(states) == n_q + n_p - 1  # the first quaternion precedes any position
    assert dec.stats.out_of_order == 0 and dec.stats.invalid == 0
    np.testing.assert_allclose(
        [s.euler[0] for s in states], ROLL, atol=1e-6
    )  # never ATTITUDE's roll
    np.testing.assert_allclose([s.pos_ned[0] for s in states], 1.0)  # never ODOMETRY's x
    assert (
        dec.attitude_source(2.0) == "ATTITUDE_QUATERNION"
        and dec.position_source(2.0) == "LOCAL_POSITION_NED"
    )


def test_fallback_to_attitude_and_odometry_when_the_preferred_streams_stop():
    dec = TelemetryDecoder(max_age=0.2)
    rates = {
        "ATTITUDE_QUATERNION": 100.0,
        "ATTITUDE": 100.0,
        "LOCAL_POSITION_NED": 50.0,
        "ODOMETRY": 30.0,
    }
    feed(dec, schedule(0.0, 1.0, rates))
    # ATTITUDE_QUATERNION stops at 1 s: ATTITUDE takes over once the quaternion is 0.2 s old
    ev = schedule(1.005, 2.0, {"ATTITUDE": 100.0, "LOCAL_POSITION_NED": 50.0, "ODOMETRY": 30.0})
    states = [s for s in feed(dec, ev) if isinstance(s, StateSample)]
    late = [s for s in states if s.t > 1.2 + 1e-9]
    np.testing.assert_allclose([s.euler[0] for s in late], ROLL + ROLL_EULER_OFFSET, atol=1e-6)
    n_att = sum(1 for t, n in ev if n == "ATTITUDE" and t > 1.2 + 1e-9)
    n_pos = sum(1 for t, n in ev if n == "LOCAL_POSITION_NED" and t > 1.2 + 1e-9)
    assert len(late) == n_att + n_pos and dec.attitude_source(2.0) == "ATTITUDE"
    # LOCAL_POSITION_NED stops as well: ODOMETRY gives position and velocity
    ev = schedule(2.005, 3.0, {"ATTITUDE": 100.0, "ODOMETRY": 30.0})
    states = [s for s in feed(dec, ev) if isinstance(s, StateSample)]
    late = [s for s in states if s.t > 2.2 + 1e-9]
    np.testing.assert_allclose([s.pos_ned[0] for s in late], 1.0 + ODOM_OFFSET)
    np.testing.assert_allclose([s.v_body[0] for s in late], 2.0, atol=1e-6)
    assert dec.position_source(3.0) == "ODOMETRY" and dec.stats.out_of_order == 0


def test_odometry_keeps_its_own_ordering_no_good_sample_dropped():
    # ATTITUDE_QUATERNION at 100 Hz and ODOMETRY (the only position source) whose
    # timestamps lag 15 ms: one shared ordering check dropped ODOMETRY samples
    dec = TelemetryDecoder()
    ev = schedule(0.0, 3.0, {"ATTITUDE_QUATERNION": 100.0, "ODOMETRY": 30.0})
    states = [s for s in feed(dec, ev) if isinstance(s, StateSample)]
    n_q = sum(1 for _, n in ev if n == "ATTITUDE_QUATERNION")
    n_o = sum(1 for _, n in ev if n == "ODOMETRY")
    assert dec.stats.out_of_order == 0
    assert len(states) == n_q + n_o - 1  # every ODOMETRY update produced a sample
    np.testing.assert_allclose([s.pos_ned[0] for s in states], 1.0 + ODOM_OFFSET)
    # ODOMETRY alone (no other stream) is a complete state at its own rate
    dec = TelemetryDecoder()
    ev = schedule(0.0, 1.0, {"ODOMETRY": 30.0})
    states = [s for s in feed(dec, ev) if isinstance(s, StateSample)]
    assert len(states) == len(ev) == 31 and dec.stats.out_of_order == 0
    np.testing.assert_allclose(states[-1].euler, [ROLL, 0.0, 0.0], atol=1e-6)
    # a genuinely older ODOMETRY is still refused
    assert dec.on_message(odom(0.5), 1.01) == [] and dec.stats.out_of_order == 1


# ---------------------------------------------------------------- foreign telemetry
def test_decoder_accepts_only_the_target_system_and_component():
    dec = TelemetryDecoder(source_filter=True)
    assert dec.on_message(lpos(0.0), 0.0) == [] and dec.stats.untargeted == 1
    dec.target = (1, 1)
    states = []
    for k in range(1, 41):
        t = k * 0.01
        states += dec.on_message(att_q(t), t)
        states += dec.on_message(lpos(t), t)
        # another vehicle (sysid 42) and a camera of our system (comp 100) on the same link
        states += dec.on_message(att_q(t, sysid=42, roll_q=[1.0, 0.0, 0.0, 0.0]), t)
        states += dec.on_message(lpos(t, sysid=42, x=-50.0, vx=-9.0), t)
        states += dec.on_message(lpos(t, compid=100, x=-60.0), t)
    assert len(states) == 80 - 1
    np.testing.assert_allclose([s.pos_ned[0] for s in states], 1.0)
    np.testing.assert_allclose([s.euler[0] for s in states], ROLL, atol=1e-6)
    assert dec.stats.foreign == 120
    assert dec.foreign_sources == {(42, 1): 80, (1, 100): 40}


class UdpPeer:
    """A PX4 stand-in socket: sends datagrams to the bridge's udpin port."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.addr = ("127.0.0.1", port)

    def send(self, *bufs: bytes) -> None:
        for b in bufs:
            self.sock.sendto(b, self.addr)

    def close(self) -> None:
        self.sock.close()


def _heartbeat(sysid=1, compid=1):
    return W.bytes(
        "heartbeat",
        2,
        12,
        px4.base_mode_flags(px4.HOLD, False),
        px4.HOLD.custom_mode,
        3,
        sysid=sysid,
        compid=compid,
    )


def _poll_all(core, t, want, tries=200):
    """Poll until ``want`` samples arrived (bounded)."""
    got = []
    for _ in range(tries):
        got += core.poll(t).samples
        if len(got) >= want:
            break
    return got


def test_bridge_publishes_state_only_from_the_target_and_reports_the_rest():
    port = free_udp_port()
    core = BridgeCore(BridgeConfig(link=LinkConfig(url=f"udpin:127.0.0.1:{port}")))
    core.open(0.0)
    peer = UdpPeer(port)
    try:
        peer.send(_heartbeat())
        _poll_all(core, 0.0, 0, tries=50)
        assert core.link.target_system == 1
        samples = []
        n_foreign = 0
        for k in range(1, 81):
            t = k * 0.01
            # 75 of 81 state samples came from sysid 42 on the unsigned SITL link
            peer.send(
                W.bytes(
                    "attitude_quaternion", k * 10, 1.0, 0.0, 0.0, 0.0, 0, 0, 0, [0.0] * 4, sysid=42
                ),
                W.bytes("local_position_ned", k * 10, -50.0, 0, 0, -9.0, 0, 0, sysid=42),
            )
            n_foreign += 2
            if k % 10 == 0:
                peer.send(
                    W.bytes(
                        "attitude_quaternion",
                        k * 10,
                        *[float(v) for v in Q_ROLL],
                        0,
                        0,
                        0,
                        [0.0] * 4,
                    ),
                    W.bytes("local_position_ned", k * 10, 1.0, 2.0, -3.0, 2.0, 0, 0),
                )
                samples += _poll_all(core, t, 2)
        samples += _poll_all(core, 0.81, 0, tries=20)
        states = [s for s in samples if isinstance(s, StateSample)]
        assert len(states) == 2 * 8 - 1
        np.testing.assert_allclose([s.pos_ned[0] for s in states], 1.0)
        np.testing.assert_allclose([s.v_body[0] for s in states], 2.0, atol=1e-6)  # roll keeps u
        st = core.status(0.81)
        assert (
            st["foreign_messages"] == str(n_foreign)
            and st["foreign_sources"] == f"42/1:{n_foreign}"
        )
        assert (
            st["attitude_source"] == "ATTITUDE_QUATERNION"
            and st["position_source"] == "LOCAL_POSITION_NED"
        )
    finally:
        peer.close()
        core.close()


# ------------------------------------------------------- rotor speeds without ESC_STATUS
def _omega_pwm(pwm):
    return np.clip(B / A * (np.asarray(pwm, float) - 1000.0) / 1000.0, LO, HI)


def test_estimated_rotor_speeds_from_actuator_output_status():
    dec = TelemetryDecoder(rotor_estimate=RotorEstimateConfig())
    pwm0, pwm1 = [1500.0, 1500.0, 1500.0, 1500.0], [1600.0, 1400.0, 1550.0, 1450.0]
    (r,) = dec.on_message(aos(1.0, pwm0), 1.0)
    assert (
        isinstance(r, RotorSample)
        and r.source == "estimated"
        and r.t_vehicle == pytest.approx(1.0)
    )
    np.testing.assert_allclose(r.omega, _omega_pwm(pwm0))
    samples = [dec.on_message(aos(1.0 + 0.02 * k, pwm1), 1.0 + 0.02 * k)[0] for k in range(1, 26)]
    # the output pwm0 was held over [1.0, 1.02]: the speeds at 1.02 are still pwm0's
    np.testing.assert_allclose(samples[0].omega, _omega_pwm(pwm0))
    # then an exact first-order response towards pwm1's speeds (seed 0 Eq. 8)
    t = 0.02 * 24
    expect = _omega_pwm(pwm1) + (_omega_pwm(pwm0) - _omega_pwm(pwm1)) * math.exp(-A * t)
    np.testing.assert_allclose(samples[-1].omega, expect, rtol=1e-9)
    assert dec.rotor_source == "estimated" and dec.stats.out_of_order == 0
    # motor outputs not among the active ones: invalid, counted
    assert dec.on_message(aos(2.0, pwm1, active=2), 2.0) == [] and dec.stats.invalid == 1


def test_servo_output_raw_is_the_fallback_and_never_a_duplicate():
    dec = TelemetryDecoder(rotor_estimate=RotorEstimateConfig())
    pwm = [1500, 1500, 1500, 1500]
    out = []
    for k in range(50):  # AOS 50 Hz + SERVO_OUTPUT_RAW 10 Hz (PX4 default)
        t = 0.02 * k
        out += dec.on_message(aos(t, pwm), t)
        if k % 5 == 0:
            out += dec.on_message(servo(t, pwm), t)
    assert len(out) == 50  # one rotor sample per AOS, none per SERVO
    # AOS stops: SERVO_OUTPUT_RAW takes over after max_gap (0.25 s)
    out = []
    for k in range(1, 11):
        t = 1.0 + 0.1 * k
        out += dec.on_message(servo(t, [1700, 1700, 1700, 1700]), t)
    assert len(out) == 8 and all(r.source == "estimated" for r in out)  # from t = 1.3 s
    np.testing.assert_allclose(out[0].omega, _omega_pwm([1700] * 4))  # source switch: restart
    # another port (SERVO_OUTPUT_RAW_1) is not the motors
    assert dec.on_message(servo(2.2, [2000] * 4, port=1), 2.2) == []
    # uint32 time_usec wrap (every 71.6 min) is not a reboot or an ordering error
    dec = TelemetryDecoder(rotor_estimate=RotorEstimateConfig(source="servo_output_raw"))
    t_wrap = 2**32 * 1e-6
    r0 = dec.on_message(servo(t_wrap - 0.01, pwm), 5000.0)
    r1 = dec.on_message(servo(t_wrap + 0.01, [1800] * 4), 5000.02)
    r2 = dec.on_message(servo(t_wrap + 0.03, [1800] * 4), 5000.04)
    assert r0 and r1 and r2 and dec.stats.out_of_order == 0 and dec.estimator.stats.restarts == 1
    assert r2[0].t_vehicle == pytest.approx(t_wrap + 0.03)


def test_measured_esc_telemetry_wins_and_the_estimate_covers_when_it_goes_stale():
    dec = TelemetryDecoder(rotor_estimate=RotorEstimateConfig(esc_timeout=0.2))
    pwm = [1500.0] * 4
    rpm = [5000, 5000, 5000, 5000]
    got = []
    for k in range(50):
        t = 0.02 * k
        got += dec.on_message(aos(t, pwm), t)
        if t < 0.5:
            got += dec.on_message(esc(t, rpm), t)
    src = [(round(r.t, 3), r.source) for r in got]
    esc_part = [s for t, s in src if t < 0.5]
    assert esc_part[0] == "estimated" and set(esc_part[1:]) == {
        "esc"
    }  # ESC wins from its first sample
    late = [(t, s) for t, s in src if t >= 0.5]
    assert all(s == "esc" or t > 0.48 + 0.2 - 1e-9 for t, s in late)
    assert {s for t, s in late if t > 0.7} == {"estimated"}
    np.testing.assert_allclose(
        [r.omega for r in got if r.source == "esc"][0], 5000 * 2 * math.pi / 60
    )
    # ESC_STATUS with 0 rpm while the outputs say the motors run: not a measurement
    r = dec.on_message(esc(1.0, [0, 0, 0, 0]), 1.0)
    assert r == [] and dec.stats.esc_zero_while_running == 1
    (r,) = dec.on_message(aos(1.02, pwm), 1.02)
    assert r.source == "estimated"
    # disarmed (900 us): 0 rpm is the truth and the ESC wins again
    dec.on_message(aos(1.04, [900.0] * 4), 1.04)
    dec.on_message(aos(1.06, [900.0] * 4), 1.06)
    (r,) = dec.on_message(esc(1.07, [0, 0, 0, 0]), 1.07)
    assert r.source == "esc" and not r.omega.any()


def test_bridge_requests_the_motor_outputs_the_estimate_needs():
    # the ROS node builds its LinkConfig from node parameters (no streams list): the bridge
    # must still request ACTUATOR_OUTPUT_STATUS, which PX4 sends only when asked
    url = f"udpin:127.0.0.1:{free_udp_port()}"
    streams = dict(BridgeCore(BridgeConfig(link=LinkConfig(url=url))).link.config.streams)
    assert streams["ACTUATOR_OUTPUT_STATUS"] == 50.0 and streams["SERVO_OUTPUT_RAW"] == 10.0
    assert streams["ATTITUDE_QUATERNION"] == 100.0  # the link's own are kept
    off = BridgeConfig(
        link=LinkConfig(url=url, streams=(("ACTUATOR_OUTPUT_STATUS", 0.0),)),
        rotor_estimate=RotorEstimateConfig(enabled=True),
    )
    assert (
        dict(BridgeCore(off).link.config.streams)["ACTUATOR_OUTPUT_STATUS"] == 0.0
    )  # configured: kept
    no = BridgeConfig(link=LinkConfig(url=url), rotor_estimate=RotorEstimateConfig(enabled=False))
    assert "ACTUATOR_OUTPUT_STATUS" not in dict(BridgeCore(no).link.config.streams)


def test_bridge_publishes_estimated_rotor_speeds_from_the_target_only():
    port = free_udp_port()
    core = BridgeCore(BridgeConfig(link=LinkConfig(url=f"udpin:127.0.0.1:{port}")))
    core.open(0.0)
    peer = UdpPeer(port)
    try:
        peer.send(_heartbeat())
        _poll_all(core, 0.0, 0, tries=50)
        rotors = []
        for k in range(1, 11):
            t = 0.02 * k
            peer.send(
                W.bytes("actuator_output_status", int(t * 1e6), 16, [1500.0] * 4 + [900.0] * 28),
                W.bytes("actuator_output_status", int(t * 1e6), 16, [2000.0] * 32, sysid=42),
            )
            rotors += [s for s in _poll_all(core, t, 1) if isinstance(s, RotorSample)]
        assert len(rotors) == 10 and {r.source for r in rotors} == {"estimated"}
        np.testing.assert_allclose([r.omega for r in rotors], [_omega_pwm([1500.0] * 4)] * 10)
        st = core.status(0.2)
        assert st["rotor_source"] == "estimated" and st["foreign_sources"] == "42/1:10"
    finally:
        peer.close()
        core.close()


# ---------------------------------------------- through BridgeCore from the simulated vehicle
def test_estimated_rotor_speeds_flow_from_the_sim_vehicle_without_esc_telemetry():
    """SimVehicle with ``esc_telemetry: false`` (SIH-like: no ESC_STATUS, PWM motor outputs)
    and the bridge of config/mavlink_bridge.yaml, lock-step over UDP on 127.0.0.1: rotor_speeds
    flow at the requested ACTUATOR_OUTPUT_STATUS rate and follow the vehicle's true rotor
    speeds (its physics integrates the same Eq. 8)."""
    import dataclasses
    import os

    from lpv_sysid.sim.px4_vehicle import SimVehicle, SimVehicleConfig

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    port = free_udp_port()
    cfg = BridgeConfig.load(os.path.join(root, "config", "mavlink_bridge.yaml"))
    cfg = dataclasses.replace(
        cfg, link=dataclasses.replace(cfg.link, url=f"udpin:127.0.0.1:{port}")
    )
    core = BridgeCore(cfg)
    veh = SimVehicle(SimVehicleConfig(url=f"udpout:127.0.0.1:{port}", esc_telemetry=False))
    core.open(0.0)
    veh.open()
    rotors, truth = [], []
    try:
        t, dt = 0.0, 0.004
        armed_sent = takeoff_sent = False
        while t < 12.0:
            t = round(t + dt, 6)
            veh.step(t)
            for s in core.poll(t).samples:
                if isinstance(s, RotorSample):
                    rotors.append(s)
                    truth.append(np.array(veh.x[12:16], dtype=float))
            if not armed_sent and t >= 2.0 and core.link.link_up(t):
                core.link.command_long(400, 1.0)  # arm
                armed_sent = True
            if armed_sent and not takeoff_sent and t >= 2.5:  # after the commander's verdict
                core.link.command_long(22, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)
                takeoff_sent = True
    finally:
        core.close()
        veh.close()
    assert armed_sent and rotors and {r.source for r in rotors} == {"estimated"}
    assert core.status(12.0)["rotor_source"] == "estimated"
    flight = [(r, w) for r, w in zip(rotors, truth) if r.t >= 2.6]  # take-off climb, then HOLD
    assert 0.9 * 50 * 9.4 <= len(flight) <= 1.1 * 50 * 9.4  # 50 Hz (config) for 9.4 s
    est = np.array([r.omega for r, _ in flight])
    ref = np.array([w for _, w in flight])
    assert ref.min() > LO and np.ptp(ref) > 50.0  # spinning, and changing
    rel = np.abs(est - ref) / ref
    # measured here: median 3e-7, max 0.042 (a 50 Hz zero-order hold of the 250 Hz control output)
    assert np.median(rel) < 0.02 and rel.max() < 0.1, (np.median(rel), rel.max())


def test_state_stamps_never_step_back_when_the_clock_estimate_drops():
    """40 ODOMETRY samples (30 Hz): the first 20 arrive 200 ms after their sample time (the
    lower envelope settles at 0.2 s), then the latency collapses to 2 ms -- the receipts stay
    in order (the backlog up to sample 24 is read at sample 19's receipt). The envelope drops
    by 198 ms. Published times never step back (the controller's out_of_order abort) and
    are never later than their receipt; the stream's offset follows the drop at CATCH_UP s
    per vehicle s, so from 0.198 / CATCH_UP s of vehicle time on the stamps are the new
    mapping (receipt - 2 ms)."""
    from lpv_sysid.mavlink.telemetry.clock import CATCH_UP

    dec = TelemetryDecoder()
    out, recv = [], []
    for k in range(40):
        t = k / 30.0  # sample time on the receiver's clock; vehicle time t + BOOT
        r = t + 0.2 if k < 20 else max(t + 0.002, recv[-1])
        recv.append(r)
        out += [s for s in dec.on_message(odom(t, lag=0.0), r)]
    t_pub = np.array([s.t for s in out])
    t_smp = np.arange(40) / 30.0
    assert len(out) == 40 and np.all(np.diff(t_pub) >= 0.0), np.diff(t_pub)
    assert np.all(t_pub <= np.array(recv) + 1e-12)
    np.testing.assert_allclose(t_pub[:20], t_smp[:20] + 0.2, atol=1e-9)  # the estimate then
    settled = 20 + int(np.ceil(0.198 / CATCH_UP * 30.0))
    assert settled < 40
    np.testing.assert_allclose(t_pub[settled:], t_smp[settled:] + 0.002, atol=1e-9)


def test_receiver_clock_keeps_stamps_already_on_the_receivers_clock():
    """MAVROS's stamps are ROS time (the bridge's clock): kept as they are whatever the
    latency of their reading (the lower envelope made them later by up to the latency it
    had allowed to rise), never later than the receipt, never more than 2 s before it."""
    dec = TelemetryDecoder(clock=ReceiverClock())
    out = []
    for k in range(40):
        t = 100.0 + k / 30.0  # MAVROS's stamp
        late = 0.2 if k < 20 else 0.002
        out += dec.on_message(odom(t - BOOT, lag=0.0), t + late)
    np.testing.assert_allclose([s.t for s in out], 100.0 + np.arange(40) / 30.0, atol=1e-9)
    # a stamp after its receipt is the receipt; one 2 s or more before it too
    (s,) = dec.on_message(odom(120.0 - BOOT, lag=0.0), 119.5)
    assert s.t == 119.5
    (s,) = dec.on_message(odom(121.0 - BOOT, lag=0.0), 124.0)
    assert s.t == 124.0
