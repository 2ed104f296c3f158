"""Unit tests of the MAVLink cores: PX4 encodings, codec robustness, signing, telemetry
decoding, the offboard state machine and the setpoint transports."""

from __future__ import annotations

import math
import os
import socket
import textwrap

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.io import frames
from lpv_sysid.mavlink import codec as mavcodec
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.bridge import (
    ATTITUDE_TARGET_IGNORE_ATTITUDE,
    ActuatorSetpoint,
    AttitudeRateTransport,
    BridgeConfig,
    BridgeCore,
    TransportContext,
    VelocitySetpoint,
    VelocityTransport,
)
from lpv_sysid.mavlink.link import (
    LinkConfig,
    MavlinkLink,
    free_udp_port,
    load_signing_key,
    parse_url,
)
from lpv_sysid.mavlink.offboard import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    OffboardConfig,
    OffboardMachine,
    SendCommand,
    SendSetpoint,
    State,
    StatusEvent,
)
from lpv_sysid.mavlink.telemetry import ImuSample, RotorSample, StateSample, TelemetryDecoder
from lpv_sysid.sim.px4_vehicle import SimVehicle, SimVehicleConfig

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOD = mavcodec.dialect_module()


# ----------------------------------------------------------------------- PX4 encodings
def test_px4_custom_mode_bits():
    assert px4.OFFBOARD.custom_mode == 6 << 16 == 0x00060000
    assert px4.HOLD.custom_mode == 0x03040000  # main 4 (AUTO) bits 16-23, sub 3 (LOITER) 24-31
    assert px4.LAND.custom_mode == 0x06040000
    assert px4.POSCTL.custom_mode == 0x00030000
    for mode in px4.MODES_BY_NAME.values():
        assert px4.decode_custom_mode(mode.custom_mode | 0xABCD) == mode  # low bits unused
    assert px4.mode_by_name("hold") == px4.HOLD
    with pytest.raises(ConfigError, match="FLY"):
        px4.mode_by_name("FLY")
    assert px4.base_mode_flags(px4.OFFBOARD, True) == 1 | 4 | 8 | 16 | 128
    assert px4.decode_flight_sw_version(px4.encode_flight_sw_version(1, 16, 2)) == (1, 16, 2, 255)


def test_px4_int_params_are_bytewise_in_the_float_field():
    for v in (0, 1, 5, 7, -1, 123456, -(2**31)):
        wire = px4.param_to_wire(v, px4.MAV_PARAM_TYPE_INT32)
        assert np.float32(wire).view(np.int32) == v  # numpy reinterpretation oracle
        assert px4.param_from_wire(wire, px4.MAV_PARAM_TYPE_INT32) == v
    assert px4.param_from_wire(1.5, px4.MAV_PARAM_TYPE_REAL32) == 1.5


def test_esc_status_definition_matches_mavlink_xml(tmp_path):
    from pymavlink.generator import mavparse

    xml = tmp_path / "esc.xml"
    xml.write_text(
        textwrap.dedent("""\
        <?xml version="1.0"?>
        <mavlink><version>3</version><messages>
          <message id="291" name="ESC_STATUS"><description>d</description>
            <field type="uint8_t" name="index">i</field>
            <field type="uint64_t" name="time_usec" units="us">t</field>
            <field type="int32_t[4]" name="rpm" units="rpm">r</field>
            <field type="float[4]" name="voltage" units="V">v</field>
            <field type="float[4]" name="current" units="A">c</field>
          </message></messages></mavlink>""")
    )
    m = mavparse.MAVXML(str(xml), mavparse.PROTOCOL_2_0).message[0]
    assert m.crc_extra == mavcodec.ESC_STATUS_CRC_EXTRA
    assert m.wire_length == mavcodec._ESC_STATUS_STRUCT.size
    tx = mavcodec.make_codec(None, 1, 1)
    buf = mavcodec.esc_status_class()(
        4, 123456789, [1000, -2000, 3, 0], [16.0] * 4, [1.5] * 4
    ).pack(tx)
    rx = mavcodec.make_codec(None, 2, 1)
    (msg,) = rx.parse_buffer(buf)
    assert msg.get_type() == "ESC_STATUS" and msg.index == 4 and msg.time_usec == 123456789
    assert msg.rpm == [1000, -2000, 3, 0] and msg.current == [1.5] * 4
    bad = bytearray(buf)
    bad[20] ^= 0x55
    (b,) = rx.parse_buffer(bytes(bad))
    assert b.get_type() == "BAD_DATA" and "CRC" in b.reason


# ---------------------------------------------------------------------- URLs and keys
@pytest.mark.parametrize(
    "url,expect",
    [
        ("udpin:127.0.0.1:14540", "udpin:127.0.0.1:14540"),
        ("udp://:14540", "udpin:0.0.0.0:14540"),
        ("udpin://127.0.0.1:14540", "udpin:127.0.0.1:14540"),
        ("udpout://10.0.0.2:14580", "udpout:10.0.0.2:14580"),
        ("udp:127.0.0.1:1", "udpin:127.0.0.1:1"),
        ("tcp://127.0.0.1:5760", "tcp:127.0.0.1:5760"),
        ("serial:///dev/ttyACM0:57600", "/dev/ttyACM0"),
        ("/dev/ttyAMA0:921600", "/dev/ttyAMA0"),
    ],
)
def test_parse_url(url, expect):
    assert parse_url(url)[0] == expect


@pytest.mark.parametrize(
    "url", ["", "udpin:127.0.0.1", "udpin:h:99999", "bogus://x:1", "udp://:x", "foo"]
)
def test_parse_url_rejects(url):
    with pytest.raises(ConfigError):
        parse_url(url)


def test_signing_key_file(tmp_path):
    raw = bytes(range(32))
    (tmp_path / "raw").write_bytes(raw)
    (tmp_path / "hex").write_text(raw.hex() + "\n")
    (tmp_path / "short").write_bytes(b"x" * 16)
    assert load_signing_key(str(tmp_path / "raw")) == raw
    assert load_signing_key(str(tmp_path / "hex")) == raw
    with pytest.raises(ConfigError, match="short.*32 raw bytes"):
        load_signing_key(str(tmp_path / "short"))
    with pytest.raises(ConfigError, match="cannot be read"):
        load_signing_key(str(tmp_path / "missing"))
    (tmp_path / "badhex").write_text("zz" * 32)
    with pytest.raises(ConfigError, match="not hexadecimal"):
        load_signing_key(str(tmp_path / "badhex"))


def _pair(tmp_path, vehicle_key: bytes | None, bridge_key: bytes | None):
    port = free_udp_port()
    vk = bk = None
    if vehicle_key is not None:
        vk = tmp_path / "vehicle.key"
        vk.write_bytes(vehicle_key)
    if bridge_key is not None:
        bk = tmp_path / "bridge.key"
        bk.write_bytes(bridge_key)
    veh = SimVehicle(
        SimVehicleConfig(url=f"udpout:127.0.0.1:{port}", signing_key_file=str(vk) if vk else None)
    )
    br = BridgeCore(
        BridgeConfig(
            link=LinkConfig(
                url=f"udpin:127.0.0.1:{port}", signing_key_file=str(bk) if bk else None
            )
        )
    )
    br.open(0.0)
    veh.open()
    t = 0.0
    for _ in range(300):  # 1.2 s of simulated time
        t += 0.004
        veh.step(t)
        br.poll(t)
    return veh, br, t


def test_signed_link_accepts_matching_key_and_rejects_wrong_key(tmp_path):
    key = os.urandom(32)
    veh, br, t = _pair(tmp_path, key, key)
    try:
        assert br.link.link_up(t)
        assert br.link.codec.signing.goodsig_count > 50 and br.link.stats.bad_signature == 0
        assert veh.link.codec.signing.goodsig_count > 0  # bridge heartbeats/requests signed
        assert veh.intervals[MOD.MAVLINK_MSG_ID_ATTITUDE_QUATERNION] == pytest.approx(0.01)
    finally:
        br.close()
        veh.close()
    veh, br, t = _pair(tmp_path, key, os.urandom(32))
    try:
        assert not br.link.link_up(t)  # nothing accepted from the vehicle
        assert br.link.stats.rx_messages == 0 and br.link.stats.bad_signature > 50
    finally:
        br.close()
        veh.close()
    veh, br, t = _pair(tmp_path, key, None)  # unsigned bridge: vehicle ignores it
    try:
        assert veh.link.stats.rx_messages == 0 and veh.link.stats.bad_signature > 0
    finally:
        br.close()
        veh.close()


# ------------------------------------------------------------------- robustness
def _valid_packets(n: int) -> list[bytes]:
    tx = mavcodec.make_codec(None, 1, 1)
    out = []
    for i in range(n):
        m = tx.attitude_quaternion_encode(i, 1.0, 0.0, 0.0, 0.0, 0.01 * i, 0.0, 0.0, [0.0] * 4)
        out.append(m.pack(tx))
        tx.seq = (tx.seq + 1) % 256
    return out


def test_udp_link_survives_garbage_and_truncated_datagrams():
    port = free_udp_port()
    link = MavlinkLink(LinkConfig(url=f"udpin:127.0.0.1:{port}"))
    link.open(0.0)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rng = np.random.default_rng(7)
    valid = _valid_packets(60)
    n_trunc = n_garbage = 0
    decoded = []
    try:
        for i, pkt in enumerate(valid):
            kind = i % 3
            if kind == 1:
                tx.sendto(
                    rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes(),
                    ("127.0.0.1", port),
                )
                n_garbage += 1
            elif kind == 2:
                tx.sendto(pkt[: int(rng.integers(1, len(pkt) - 1))], ("127.0.0.1", port))
                n_trunc += 1
            tx.sendto(pkt, ("127.0.0.1", port))
            decoded += link.poll(float(i))
        for _ in range(50):
            decoded += link.poll(100.0)
    finally:
        tx.close()
        link.close()
    aq = [m for m in decoded if m.get_type() == "ATTITUDE_QUATERNION"]
    # every whole datagram is decoded, with its content, regardless of the junk around it
    assert [m.time_boot_ms for m in aq] == list(range(60))
    assert link.stats.truncated >= n_trunc
    assert (
        link.stats.bad_data + link.stats.truncated + link.stats.unknown_msgid
        >= n_garbage + n_trunc
    )
    assert link.stats.rx_datagrams == 60 + n_garbage + n_trunc


def test_stream_parser_resynchronises_after_garbage():
    """Serial-like byte stream: junk, then >= 300 filler bytes, then packets -> all decoded."""
    rng = np.random.default_rng(11)
    rx = mavcodec.make_codec(None, 2, 1)
    valid = _valid_packets(20)
    stream = b"".join(
        rng.integers(0, 256, 200, dtype=np.uint8).tobytes() + b"\0" * 300 + p for p in valid
    )
    msgs = []
    for i in range(0, len(stream), 37):  # arbitrary chunking
        msgs += rx.parse_buffer(stream[i : i + 37]) or []
    good = [m for m in msgs if m.get_type() == "ATTITUDE_QUATERNION"]
    assert [m.time_boot_ms for m in good] == list(range(20))
    assert all(
        m.get_type() in ("ATTITUDE_QUATERNION", "BAD_DATA") or m.get_type().startswith("UNKNOWN")
        for m in msgs
    )


# -------------------------------------------------------------------- telemetry
def test_telemetry_body_velocity_against_scipy_rotation():
    dec = TelemetryDecoder()
    rng = np.random.default_rng(3)
    for k in range(20):
        rot = Rotation.from_euler(
            "ZYX", rng.uniform([-3, -1.2, -1.2], [3, 1.2, 1.2])
        )  # psi, theta, phi
        x, y, z, w = rot.as_quat()
        v_ned = rng.normal(0, 3, 3)
        t = 1.0 + k
        dec.on_message(MOD.MAVLink_local_position_ned_message(int(t * 1000), 1, 2, -3, *v_ned), t)
        (s,) = dec.on_message(
            MOD.MAVLink_attitude_quaternion_message(
                int(t * 1000), w, x, y, z, 0.1, -0.2, 0.3, [0.0] * 4
            ),
            t,
        )
        assert isinstance(s, StateSample)
        np.testing.assert_allclose(s.v_body, rot.inv().apply(np.float32(v_ned)), atol=1e-5)
        np.testing.assert_allclose(s.euler[::-1], rot.as_euler("ZYX"), atol=1e-5)
        np.testing.assert_allclose(s.euler, frames.euler_from_quaternion(s.q_wxyz), atol=1e-12)
        np.testing.assert_allclose(s.omega, np.float32([0.1, -0.2, 0.3]), atol=0)


def test_telemetry_rejects_nan_out_of_order_and_reports_staleness():
    dec = TelemetryDecoder(max_age=0.2)
    assert (
        dec.on_message(
            MOD.MAVLink_attitude_quaternion_message(1000, 1, 0, 0, 0, 0, 0, 0, [0] * 4), 1.0
        )
        == []
    )
    assert dec.on_message(MOD.MAVLink_local_position_ned_message(1000, 0, 0, 0, 1, 0, 0), 1.0)
    assert (
        dec.on_message(
            MOD.MAVLink_attitude_quaternion_message(900, 1, 0, 0, 0, 0, 0, 0, [0] * 4), 1.01
        )
        == []
    )
    assert dec.stats.out_of_order == 1
    assert (
        dec.on_message(
            MOD.MAVLink_local_position_ned_message(1100, 0, 0, 0, float("nan"), 0, 0), 1.1
        )
        == []
    )
    assert dec.stats.invalid == 1
    age = dec.staleness(1.5)
    assert age["attitude"] == pytest.approx(0.5) and age["position"] == pytest.approx(0.5)
    assert math.isinf(age["imu"])
    assert dec.latest_state(1.5) is None  # older than max_age: no state
    esc = mavcodec.esc_status_class()(0, 5_000_000, [6000, 6000, -6000, 0], [0] * 4, [0] * 4)
    (r,) = dec.on_message(esc, 1.6)
    assert isinstance(r, RotorSample)
    np.testing.assert_allclose(r.omega, [200 * math.pi, 200 * math.pi, 200 * math.pi, 0.0])
    (imu,) = dec.on_message(
        MOD.MAVLink_highres_imu_message(
            7, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0, 0, 0, 0, 0, 0, 0, 0
        ),
        1.7,
    )
    assert isinstance(imu, ImuSample)
    np.testing.assert_allclose(imu.accel_frd, np.float32([0.1, 0.2, -9.8]))


# ------------------------------------------------------------ offboard machine
def _kinds(actions, cls):
    return [a for a in actions if isinstance(a, cls)]


def _drive(m, t0, t1, dt=0.01, cmd=True):
    acts = []
    t = t0
    while t < t1 - 1e-9:
        t += dt
        if cmd:
            acts += m.on_command(t, "sp")
        acts += m.step(t)
    return acts, t


def test_machine_prestream_switch_arm_active():
    m = OffboardMachine(
        OffboardConfig(arm=True, setpoint_rate_hz=20.0, prestream_time=1.2, send_on_command=False),
        neutral_setpoint="zero",
    )
    assert m.step(0.5) == []  # IDLE: nothing streamed
    acts = m.start(1.0)
    assert m.state == State.PRESTREAM
    more, t = _drive(m, 1.0, 2.2, cmd=False)
    acts += more
    sps = _kinds(acts, SendSetpoint)
    assert all(a.setpoint == "zero" for a in sps)  # no command yet: neutral setpoint
    assert 23 <= len(sps) <= 25 and m.state == State.PRESTREAM  # 20 Hz for 1.2 s
    acts, t = _drive(m, t, 2.3)
    cmds = _kinds(acts, SendCommand)
    assert m.state == State.SWITCHING and cmds == [
        SendCommand(MAV_CMD_DO_SET_MODE, (1.0, 6.0, 0.0), 1)
    ]
    assert m.on_ack(t, MAV_CMD_DO_SET_MODE, 0) == []  # accepted, waiting for HEARTBEAT
    m.on_heartbeat(t + 0.1, px4.OFFBOARD, False)
    assert m.state == State.SWITCHING  # ack_settle_s: a verdict may follow
    acts = m.step(t + 0.25)
    assert m.state == State.ARMING
    assert _kinds(acts, SendCommand) == [SendCommand(MAV_CMD_COMPONENT_ARM_DISARM, (1.0, 0.0), 1)]
    assert (
        m.on_ack(t + 0.3, MAV_CMD_DO_SET_MODE, 0) == []
    )  # late duplicate of the mode ACK: ignored
    m.on_ack(t + 0.3, MAV_CMD_COMPONENT_ARM_DISARM, 0)
    m.on_ack(t + 0.3, MAV_CMD_COMPONENT_ARM_DISARM, 0)  # duplicated ACK: harmless
    m.on_command(t + 0.35, "sp")
    m.on_heartbeat(t + 0.4, px4.OFFBOARD, True)
    assert m.state == State.ARMING
    m.step(t + 0.55)
    assert m.state == State.OFFBOARD_ACTIVE


def test_machine_retries_then_fails_and_lost_ack_confirmed_by_heartbeat():
    cfg = OffboardConfig(max_retries=2, ack_timeout=0.2, prestream_time=1.1)
    m = OffboardMachine(cfg, "zero")
    m.start(0.0)
    acts, t = _drive(m, 0.0, 1.2)
    assert m.state == State.SWITCHING
    sent = [1]
    for _ in range(3):
        acts = m.on_ack(t, MAV_CMD_DO_SET_MODE, 1)  # TEMPORARILY_REJECTED
        sent += [c.attempt for c in _kinds(acts, SendCommand)]
        t += 0.01
    assert sent == [1, 2, 3] and m.state == State.FAILED
    assert "rejected" in m.reason
    assert _kinds(m.step(t + 1.0), SendSetpoint) == []  # FAILED: stream stopped
    # ACK lost but the HEARTBEAT shows OFFBOARD: proceed
    m2 = OffboardMachine(cfg, "zero")
    m2.start(0.0)
    _, t = _drive(m2, 0.0, 1.2)
    m2.on_heartbeat(t + 0.05, px4.OFFBOARD, False)
    m2.on_command(t + 0.3, "sp")
    m2.step(t + 0.3)  # ack_settle_s after sending
    assert m2.state == State.OFFBOARD_ACTIVE
    # no ACK at all: resent every ack_timeout, FAILED after max_retries
    m3 = OffboardMachine(cfg, "zero")
    m3.start(0.0)
    acts, t = _drive(m3, 0.0, 3.0)
    assert [c.attempt for c in _kinds(acts, SendCommand)] == [1, 2, 3]
    assert m3.state == State.FAILED and "no COMMAND_ACK" in m3.reason


def _active(cfg):
    m = OffboardMachine(cfg, "zero")
    m.start(0.0)
    _, t = _drive(m, 0.0, 1.3)
    m.on_ack(t, MAV_CMD_DO_SET_MODE, 0)
    m.on_heartbeat(t, px4.OFFBOARD, True)
    _, t = _drive(m, t, t + 0.25)  # ack_settle_s
    assert m.state == State.OFFBOARD_ACTIVE
    return m, t


def test_machine_stale_input_hands_back_and_stops_stream():
    cfg = OffboardConfig(input_timeout=0.25, handback_mode="POSCTL")
    m, t = _active(cfg)
    last = t
    acts, t2 = _drive(m, t, t + 1.0, cmd=False)
    ev = [
        a
        for a in acts
        if isinstance(a, StatusEvent) and a.state == "HANDBACK" and a.previous != "HANDBACK"
    ]
    assert len(ev) == 1 and cfg.input_timeout < ev[0].t - last <= cfg.input_timeout + 0.01 + 1e-9
    idx = acts.index(ev[0])
    # hand-back in progress: only the neutral setpoint is streamed, never the last command
    assert {a.setpoint for a in _kinds(acts[idx:], SendSetpoint)} <= {"zero"}
    assert _kinds(acts[idx:], SendCommand)[0] == SendCommand(
        MAV_CMD_DO_SET_MODE, (1.0, 3.0, 0.0), 1
    )
    m.on_ack(t2 + 0.01, MAV_CMD_DO_SET_MODE, 0)
    m.on_heartbeat(t2 + 0.02, px4.POSCTL, True)
    m.step(t2 + 0.25)
    assert m.state == State.FAILED and "stale input" in m.reason and m.confirmed_mode == px4.POSCTL
    assert _kinds(m.step(t2 + 1.0), SendSetpoint) == []  # confirmed: stream stopped


def test_machine_abort_shutdown_link_loss_and_pilot_takeover():
    m, t = _active(OffboardConfig(handback_mode="LAND"))
    m.on_command(t, "sp")
    acts = m.abort(t, "operator")
    assert m.state == State.HANDBACK and _kinds(acts, SendCommand)[0].params == (1.0, 4.0, 6.0)
    m.on_heartbeat(t + 0.3, px4.LAND, True)
    assert m.state == State.DONE and "LAND" in m.reason
    m, t = _active(OffboardConfig())
    m.on_link(t, True)
    m.on_command(t, "sp")
    m.on_link(t + 0.01, False)
    assert m.state == State.HANDBACK and "link lost" in m.reason
    m, t = _active(OffboardConfig())
    m.on_command(t, "sp")
    acts = m.on_heartbeat(t + 0.01, px4.POSCTL, True)  # pilot switched mode: do not fight
    assert m.state == State.FAILED and _kinds(acts, SendCommand) == []
    m = OffboardMachine(OffboardConfig(), "zero")
    m.start(0.0)
    acts = m.shutdown(0.5)  # still pre-streaming: just stop
    assert m.state == State.DONE and _kinds(acts, SendCommand) == []


def test_machine_without_neutral_setpoint_never_streams_stale_commands():
    m = OffboardMachine(OffboardConfig(input_timeout=0.2), neutral_setpoint=None)
    m.start(0.0)
    acts, t = _drive(m, 0.0, 1.0, cmd=False)
    assert _kinds(acts, SendSetpoint) == [] and m.state == State.PRESTREAM  # waits for commands
    acts, t = _drive(m, t, 2.3)
    assert m.state == State.SWITCHING and all(
        a.setpoint == "sp" for a in _kinds(acts, SendSetpoint)
    )
    acts, t = _drive(m, t, t + 0.5, cmd=False)  # commands stop while switching
    assert m.state == State.HANDBACK and "stale input during SWITCHING" in m.reason
    assert _kinds(acts, SendSetpoint)[-1:] and all(
        a.setpoint == "sp" for a in _kinds(acts, SendSetpoint)
    )


@pytest.mark.parametrize(
    "bad,match",
    [
        ({"setpoint_rate_hz": 2.0}, "setpoint_rate_hz"),
        ({"prestream_time": 1.0}, "prestream_time"),
        ({"handback_mode": "ACRO"}, "handback_mode"),
        ({"max_retries": -1}, "max_retries"),
        ({"arm": "yes"}, "arm"),
        ({"bogus": 1}, "bogus"),
    ],
)
def test_offboard_config_validation(bad, match):
    with pytest.raises(ConfigError, match=match):
        OffboardConfig.from_dict(bad)


# ------------------------------------------------------------------- transports
def test_velocity_transport_masks_and_frames():
    codec = mavcodec.make_codec(None, 1, 191)
    ctx = TransportContext(1234, 1, 1, q_wxyz=np.array([math.cos(0.3), 0, 0, math.sin(0.3)]))
    (m,) = VelocityTransport("body_ned", use_yaw_rate=False).encode(
        codec, VelocitySetpoint((1, 2, 3), 0.4), ctx
    )
    assert m.type_mask == 0x0FC7 and m.coordinate_frame == 8 and (m.vx, m.vy, m.vz) == (1, 2, 3)
    assert m.yaw_rate == 0.0
    (m,) = VelocityTransport("local_ned").encode(codec, VelocitySetpoint((1, 0, 0), 0.4), ctx)
    assert m.type_mask == 0x07C7 and m.coordinate_frame == 1 and m.yaw_rate == pytest.approx(0.4)
    np.testing.assert_allclose([m.vx, m.vy, m.vz], [math.cos(0.6), math.sin(0.6), 0.0], atol=1e-12)
    with pytest.raises(LpvSysidError, match="NaN"):
        VelocityTransport().encode(codec, VelocitySetpoint((1, float("nan"), 0)), ctx)


def test_attitude_rate_transport_inverts_px4_rate_p_and_allocation():
    from lpv_sysid.models.quadrotor import Quadrotor

    quad = Quadrotor()
    tr = AttitudeRateTransport(quad.params.arm_length, rate_p=(0.15, 0.17, 0.2))
    codec = mavcodec.make_codec(None, 1, 191)
    omega = np.array([0.2, -0.1, 0.05])
    u = np.array([0.55, 0.006, -0.004, 0.03])
    (m,) = tr.encode(codec, ActuatorSetpoint(tuple(u)), TransportContext(0, 1, 1, omega=omega))
    assert m.type_mask == ATTITUDE_TARGET_IGNORE_ATTITUDE
    # PX4 side: tau = K_p (omega_sp - omega); motor_i = T + A_i tau (unit quad-X allocation)
    tau = np.array([0.15, 0.17, 0.2]) * (
        np.array([m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate]) - omega
    )
    alloc = np.array([[1, -1, 1, 1], [1, 1, -1, 1], [1, 1, 1, -1], [1, -1, -1, -1]], dtype=float)
    u_esc = alloc @ np.r_[m.thrust, tau]
    np.testing.assert_allclose(u_esc, quad.mix_inv @ u, atol=1e-6)  # seed 0 Eq. (8) oracle
    assert tr.neutral() is None


# ------------------------------------------------------------------ configuration
def test_bridge_config_file_and_errors(tmp_path):
    cfg = BridgeConfig.load(os.path.join(ROOT, "config", "mavlink_bridge.yaml"))
    assert cfg.link.url == "udpin:127.0.0.1:14540" and cfg.offboard.chain == (px4.HOLD, px4.LAND)
    assert dict(cfg.link.streams)["ESC_STATUS"] > 0
    bad = tmp_path / "bad.yaml"
    bad.write_text("link: [unclosed\n")
    with pytest.raises(ConfigError, match="malformed YAML"):
        BridgeConfig.load(str(bad))
    bad.write_text("link:\n  urll: udpin:1.2.3.4:5\n")
    with pytest.raises(ConfigError, match="urll"):
        BridgeConfig.load(str(bad))
    bad.write_text("link:\n  streams: {NOT_A_MESSAGE: 10}\n")
    with pytest.raises(ConfigError, match="NOT_A_MESSAGE"):
        BridgeConfig.load(str(bad))
    with pytest.raises(ConfigError, match="command transport"):
        BridgeConfig.from_dict({"command": "actuator_motors"})


def test_bridge_rejects_bad_commands_without_sending():
    core = BridgeCore(BridgeConfig(link=LinkConfig(url=f"udpin:127.0.0.1:{free_udp_port()}")))
    core.open(0.0)
    try:
        assert core.on_velocity_reference(0.1, [1.0, float("nan"), 0.0]) is False
        assert core.on_velocity_reference(0.1, [1.0, 2.0]) is False
        assert (
            core.on_actuator_command(0.1, [0.5, 0, 0, 0]) is False
        )  # wrong mode: velocity bridge
        assert core.on_velocity_reference(0.2, [1.0, 0.0, 0.0], stamp=5.0) is True
        assert core.on_velocity_reference(0.3, [1.0, 0.0, 0.0], stamp=4.0) is False  # out of order
        out = core.poll(0.3)
        errs = [e for e in out.events if isinstance(e, StatusEvent) and e.level == "error"]
        assert len(errs) == 4 and "NaN" not in errs[1].reason and "out-of-order" in errs[3].reason
        assert (
            core.rejected_commands == 4 and core.link.stats.tx_messages == 1
        )  # only the heartbeat
        assert core.status(0.3)["state"] == "IDLE"
    finally:
        core.close()
