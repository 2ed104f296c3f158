"""transport mavros (mavros_msgs) against a real PX4 SITL (SIH) through a MAVROS stand-in.

No real MAVROS here (test_mavros_real.py flies that when a ROS with mavros exists); this
test puts the bridge runtime on a real PX4 with a small pymavlink stand-in that does what
MAVROS 2's plugins do with the same MAVLink (sys_status: HEARTBEAT -> State, set_mode ->
SET_MODE with base_mode CUSTOM_MODE_ENABLED | the last HEARTBEAT's armed flag, answered
``mode_sent`` at once; command: arming -> COMMAND_LONG 400 answered with PX4's
COMMAND_ACK; setpoint_raw: PositionTarget FLU -> SET_POSITION_TARGET_LOCAL_NED FRD,
``yaw_rate`` negated; param: PX4's PARAM_VALUE as ROS parameters; rc_io: SERVO_OUTPUT_RAW
-> rc/out; vehicle_info_get from HEARTBEAT + AUTOPILOT_VERSION, flight_sw_version 0 until
PX4's AUTOPILOT_VERSION came -- which the bridge asks for through cmd/command, COMMAND_LONG
512 answered with PX4's COMMAND_ACK; the preflight's health:
SYS_STATUS -> battery, GPS_RAW_INT -> gpsstatus/gps1/raw, ESTIMATOR_STATUS ->
estimator_status, HOME_POSITION -> home_position/home). Skipped without
``PX4_SITL_DIR``.

Oracles are PX4's: its HEARTBEAT modes and arming, its PARAM_VALUE answers, its altitude.
The flight: the preflight refuses ``start`` with PX4 SITL's default COM_OBL_RC_ACT 0
(Position, no stick input); COM_OBL_RC_ACT 5 is set (PARAM_SET), ``start`` again: OFFBOARD
and arming confirmed, a climb on velocity setpoints; the hand-back chain POSCTL, HOLD: PX4
refuses POSCTL without RC (its COMMAND_ACK never reaches MAVROS's set_mode), never shows
it, and the bridge ends DONE only when the HEARTBEAT shows HOLD. Bounded wall-clock loops,
generous timeouts (load ~10 on 2 cores).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from mavros_msgs.msg import State
from mavros_msgs.srv import CommandBool, CommandLong, MessageInterval, SetMode, VehicleInfoGet
from px4_sitl import Px4Sitl, find_px4
from rcl_interfaces.msg import ParameterValue
from rcl_interfaces.srv import GetParameters

from lpv_sysid.flight.bridge import PARSERS, SPECS, BridgeRuntime
from lpv_sysid.io import messages
from lpv_sysid.mavlink import px4
from lpv_sysid.mavlink.bridge import MAVROS_MODE_NAMES, ServiceRequest

PX4_DIR, SKIP_REASON = find_px4()
pytestmark = pytest.mark.skipif(PX4_DIR is None, reason=SKIP_REASON)
INSTANCE = 17
#: PX4 SITL instance N > 9 sends its offboard link from UDP 14580+N to 127.0.0.1:14549 (one
#: port for all, px4-rc.mavlink) until it hears a peer, then answers the peer: like MAVROS's
#: ``fcu_url udp://:14540+N@127.0.0.1:14580+N`` the stand-in sends first (a HEARTBEAT)
URL = f"udpout:127.0.0.1:{14580 + INSTANCE}"
F = messages.MsgFactory.rclpy()  # the in-repo rclpy stand-in's classes (test/support)
MAVROS_NAME = {m.custom_mode: name for m, name in MAVROS_MODE_NAMES.items()}


class MavrosStandIn:
    """MAVROS 2's behaviour on the MAVLink of one PX4 (module docstring)."""

    def __init__(self, url: str, rt: BridgeRuntime) -> None:
        from pymavlink import mavutil

        self.m = mavutil.mavlink_connection(
            url, source_system=1, source_component=191, dialect="development"
        )
        self.rt = rt
        self.sysid = 0
        self._t_hello = -1e9
        self.hb = None
        self.version = None
        self.params: dict[str, float | int] = {}
        self.pending: list[tuple[int, ServiceRequest]] = []  # COMMAND_LONG awaiting ACK
        self.modes: list[tuple[str, bool]] = []  # PX4's HEARTBEAT, on change
        self.acks: list[tuple[int, int]] = []
        self.z: list[float] = []
        self.yaw: list[float] = []  # PX4's NED yaw [rad] of every ATTITUDE_QUATERNION
        self.att = None
        self.log: list[tuple[str, str]] = []
        self.t_hb = 0.0
        self.seen: set[str] = set()  # the health messages PX4 sent

    # -- PX4 -> ROS ------------------------------------------------------------------
    def pump(self, now: float) -> None:
        if not self.sysid and now - self._t_hello > 1.0:  # MAVROS's 1 Hz HEARTBEAT
            self._t_hello = now
            self.m.mav.heartbeat_send(18, 8, 0, 0, 0)
        while True:
            msg = self.m.recv_match(blocking=False)
            if msg is None:
                return
            t = msg.get_type()
            if msg.get_srcComponent() != 1 or (self.sysid and msg.get_srcSystem() != self.sysid):
                continue
            if t == "HEARTBEAT" and msg.autopilot == 12:
                self.sysid, self.hb, self.t_hb = msg.get_srcSystem(), msg, now
                armed = bool(msg.base_mode & px4.MAV_MODE_FLAG_SAFETY_ARMED)
                name = MAVROS_NAME.get(msg.custom_mode, f"CMODE({msg.custom_mode})")
                if not self.modes or self.modes[-1] != (name, armed):
                    self.modes.append((name, armed))
                st = State(
                    header=messages.header_msg(F, round(now * 1e9)),
                    connected=True,
                    armed=armed,
                    mode=name,
                    system_status=msg.system_status,
                )
                self.out(self.rt.on_message("mavros_state", st, now))
            elif t == "AUTOPILOT_VERSION":
                self.version = msg
            elif t == "PARAM_VALUE":
                name = px4.param_id_str(msg.param_id)
                self.params[name] = px4.param_from_wire(msg.param_value, msg.param_type)
            elif t == "COMMAND_ACK":
                self.acks.append((msg.command, msg.result))
                for k, (cmd, req) in enumerate(self.pending):
                    if cmd == msg.command:
                        del self.pending[k]
                        ok = msg.result == px4.MAV_RESULT_ACCEPTED
                        if req.key == "arming":
                            resp = CommandBool.Response(success=ok, result=msg.result)
                        elif req.key == "request_message":
                            resp = CommandLong.Response(success=ok, result=msg.result)
                        else:
                            resp = MessageInterval.Response(success=ok)
                        self.out(self.rt.on_service_answer(req, resp, now))
                        break
            elif t == "ATTITUDE_QUATERNION":
                self.att = msg
                self.yaw.append(float(px4_euler(msg.q1, msg.q2, msg.q3, msg.q4)[2]))
            elif t == "LOCAL_POSITION_NED" and self.att is not None:
                a = self.att
                euler = px4_euler(a.q1, a.q2, a.q3, a.q4)
                v_ned = np.array([msg.vx, msg.vy, msg.vz])
                v_body = rot(euler).T @ v_ned
                odom = messages.odometry_from_state(
                    F,
                    round(now * 1e9),
                    [msg.x, msg.y, msg.z],
                    euler,
                    v_body,
                    [a.rollspeed, a.pitchspeed, a.yawspeed],
                    frame_id="map",
                )
                self.z.append(msg.z)
                self.out(self.rt.on_message("mavros_odom", odom, now))
            elif t in HEALTH:
                self.seen.add(t)
                self.out(self.rt.on_message(HEALTH[t], mavros_health_msg(msg, now), now))
            elif t == "SERVO_OUTPUT_RAW" and msg.port == 0:
                rc = F(
                    "mavros_msgs/msg/RCOut",
                    header=messages.header_msg(F, round(now * 1e9)),
                    channels=[getattr(msg, f"servo{k}_raw") for k in range(1, 9)],
                )
                self.out(self.rt.on_message("mavros_rc_out", rc, now))

    # -- ROS -> PX4 ------------------------------------------------------------------
    def out(self, items) -> None:
        for key, item in items:
            if key == "status":
                continue
            if key == "mavros_local":
                # setpoint_raw local_cb, FRAME_BODY_NED: baselink (FLU) -> aircraft (FRD)
                v = item.velocity
                self.m.mav.set_position_target_local_ned_send(
                    0,
                    self.sysid,
                    1,
                    item.coordinate_frame,
                    item.type_mask,
                    0.0,
                    0.0,
                    0.0,
                    v.x,
                    -v.y,
                    -v.z,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    -item.yaw_rate,
                )
            elif key == "mavros_attitude":
                # setpoint_raw attitude_cb: body_rate baselink (FLU) -> aircraft (FRD),
                # thrust * thrust_scaling (1) in [0, 1]; the orientation is ignored (mask)
                w = item.body_rate
                self.m.mav.set_attitude_target_send(
                    0,
                    self.sysid,
                    1,
                    item.type_mask,
                    [1.0, 0.0, 0.0, 0.0],
                    w.x,
                    -w.y,
                    -w.z,
                    min(1.0, max(0.0, item.thrust)),
                )
            elif isinstance(item, ServiceRequest):
                self.serve(item)
        for level, text in self.rt.take_log():
            self.log.append((level, text))

    def serve(self, req: ServiceRequest) -> None:
        now = time.monotonic()
        if req.key == "set_mode":
            custom = {v: k for k, v in MAVROS_NAME.items()}.get(req.fields["custom_mode"])
            if custom is None:
                self.out(self.rt.on_service_answer(req, SetMode.Response(mode_sent=False), now))
                return
            armed = self.hb is not None and self.hb.base_mode & px4.MAV_MODE_FLAG_SAFETY_ARMED
            base = px4.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
                px4.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
            )
            self.m.mav.set_mode_send(self.sysid, base, custom)
            self.out(self.rt.on_service_answer(req, SetMode.Response(mode_sent=True), now))
        elif req.key == "arming":
            value = 1.0 if req.fields["value"] else 0.0
            self.m.mav.command_long_send(self.sysid, 1, 400, 0, value, 0, 0, 0, 0, 0, 0)
            self.pending.append((400, req))
        elif req.key == "message_interval":
            us = 1e6 / req.fields["message_rate"]
            self.m.mav.command_long_send(
                self.sysid, 1, 511, 0, req.fields["message_id"], us, 0, 0, 0, 0, 0
            )
            self.pending.append((511, req))
        elif req.key == "param_get":
            values = []
            for name in req.fields["names"]:
                v = self.params.get(name)
                if v is None:
                    self.m.mav.param_request_read_send(self.sysid, 1, name.encode(), -1)
                    values.append(ParameterValue(type=0))
                elif isinstance(v, int):
                    values.append(ParameterValue(type=2, integer_value=int(v)))
                else:
                    values.append(ParameterValue(type=3, double_value=float(v)))
            self.out(self.rt.on_service_answer(req, GetParameters.Response(values=values), now))
        elif req.key == "request_message":
            f = req.fields
            self.m.mav.command_long_send(
                self.sysid, 1, f["command"], f["confirmation"], f["param1"], 0, 0, 0, 0, 0, 0
            )
            self.pending.append((f["command"], req))
        elif req.key == "vehicle_info":
            if self.hb is None:
                resp = VehicleInfoGet.Response(success=False, vehicles=[])
            else:  # MAVROS 2: from the HEARTBEAT, the version fields once it has them
                v = self.version
                info = F(
                    "mavros_msgs/msg/VehicleInfo",
                    sysid=self.sysid,
                    compid=1,
                    autopilot=self.hb.autopilot,
                    type=self.hb.type,
                    capabilities=int(v.capabilities) if v is not None else 0,
                    flight_sw_version=int(v.flight_sw_version) if v is not None else 0,
                    available_info=3
                    if v is not None
                    else 1,  # HAVE_INFO_HEARTBEAT | AUTOPILOT_VERSION
                )
                resp = VehicleInfoGet.Response(success=True, vehicles=[info])
            self.out(self.rt.on_service_answer(req, resp, now))

    def set_param_int(self, name: str, value: int) -> None:
        wire = px4.param_to_wire(value, px4.MAV_PARAM_TYPE_INT32)
        self.m.mav.param_set_send(self.sysid, 1, name.encode(), wire, px4.MAV_PARAM_TYPE_INT32)
        self.params.pop(name, None)


#: PX4's health messages -> the MAVROS topic key they become
HEALTH = {
    "SYS_STATUS": "mavros_battery",
    "GPS_RAW_INT": "mavros_gps_raw",
    "ESTIMATOR_STATUS": "mavros_estimator",
    "HOME_POSITION": "mavros_home",
}


def mavros_health_msg(msg, now):
    """MAVROS 2's message of a PX4 health message: sys_status (SYS_STATUS -> BatteryState,
    ``battery_remaining / 100.0f``), gps_status (GPS_RAW_INT -> GPSRAW), sys_status
    (ESTIMATOR_STATUS flags -> EstimatorStatus booleans), home_position (HOME_POSITION ->
    HomePosition: geo in degrees / metres, position NED -> ENU)."""
    h = messages.header_msg(F, round(now * 1e9))
    t = msg.get_type()
    if t == "SYS_STATUS":
        pct = float(np.float32(msg.battery_remaining) / np.float32(100.0))
        volts = float(np.float32(msg.voltage_battery) / np.float32(1000.0))
        return F("sensor_msgs/msg/BatteryState", header=h, voltage=volts, percentage=pct)
    if t == "GPS_RAW_INT":
        return F(
            "mavros_msgs/msg/GPSRAW",
            header=h,
            fix_type=msg.fix_type,
            satellites_visible=msg.satellites_visible,
        )
    if t == "ESTIMATOR_STATUS":
        names = [
            "attitude", "velocity_horiz", "velocity_vert", "pos_horiz_rel", "pos_horiz_abs",
            "pos_vert_abs", "pos_vert_agl", "const_pos_mode", "pred_pos_horiz_rel",
            "pred_pos_horiz_abs", "gps_glitch", "accel_error",
        ]  # fmt: skip
        flags = {f"{n}_status_flag": bool(msg.flags & (1 << k)) for k, n in enumerate(names)}
        return F("mavros_msgs/msg/EstimatorStatus", header=h, **flags)
    geo = F(
        "geographic_msgs/msg/GeoPoint",
        latitude=msg.latitude / 1e7,
        longitude=msg.longitude / 1e7,
        altitude=msg.altitude / 1e3,
    )
    pos = F("geometry_msgs/msg/Point", x=float(msg.y), y=float(msg.x), z=float(-msg.z))
    return F("mavros_msgs/msg/HomePosition", header=h, geo=geo, position=pos)


def px4_euler(w, x, y, z):
    from lpv_sysid.io import frames

    return frames.euler_from_quaternion(np.array([w, x, y, z]))


def rot(euler):
    from lpv_sysid.io import frames

    return frames.rotation_from_euler(euler)


def test_px4_sitl_through_mavros_semantics_preflight_offboard_climb_rejected_posctl_handback():
    defaults = {n: d for n, (d, _) in SPECS.items()}
    params = {
        **defaults,
        "transport": "mavros",
        "mavros.interfaces": "mavros_msgs",
        "command": "velocity",
        "offboard.arm": True,
        "offboard.handback_chain": ["POSCTL", "HOLD", "LAND"],
        "offboard.mode_confirm_timeout": 5.0,
        "offboard.ack_timeout": 2.0,
        "offboard.input_timeout": 1.0,
    }
    rt = BridgeRuntime(params, F, "/lpv_sysid/mavlink_bridge", 60.0, 3.0)
    with Px4Sitl(PX4_DIR, instance=INSTANCE, boot_timeout=240.0) as sitl:
        mav = MavrosStandIn(URL, rt)
        rt.open(time.monotonic())
        ref = {"v": None}

        def run(seconds, until=None):
            end = time.monotonic() + seconds
            next_ref = 0.0
            while time.monotonic() < end:
                now = time.monotonic()
                mav.pump(now)
                if ref["v"] is not None and now >= next_ref:
                    next_ref = now + 0.05
                    msg = messages.twist_reference_msg(F, round(now * 1e9), ref["v"], 0.0)
                    parsed = PARSERS["velocity_reference"](msg)
                    mav.out(rt.on_sample("velocity_reference", parsed, now))
                mav.out(rt.on_timer(now))
                if mav.sysid and now - mav.t_hb < 0.01:  # MAVLink heartbeat of "MAVROS"
                    mav.m.mav.heartbeat_send(18, 8, 0, 0, 0)
                if until is not None and until():
                    return True
                time.sleep(0.004)
            return False

        state = lambda: rt.core.state.value  # noqa: E731
        ev = rt.evidence
        assert ev is not None
        # MAVROS connected, PX4's parameters and version in (the version asked by the
        # bridge through cmd/command: the stand-in's MAVROS never requests it itself)
        assert run(
            90.0, until=lambda: not ev.missing_params() and ev.firmware_known() and mav.z
        ), (mav.params, mav.acks, sitl.log_tail())
        assert (512, px4.MAV_RESULT_ACCEPTED) in mav.acks, mav.acks
        ok, why, out = rt.start(time.monotonic())
        mav.out(out)
        assert not ok and "COM_OBL_RC_ACT: 0 (POSITION)" in why, why
        assert mav.params.get("COM_OBL_RC_ACT") == 0  # PX4 SITL's default
        # PX4's own health, as MAVROS's battery / gpsstatus / estimator_status /
        # home_position topics carry it: judged GO (only the parameter refuses)
        assert "battery" not in why and "GPS" not in why and "EKF" not in why, (why, mav.seen)
        assert "home position" not in why, why
        table = [t for _, t in mav.log if t.startswith("preflight (MAVROS)")][-1]
        rows = {r.split()[0]: r for r in table.splitlines() if r.strip()}
        # PX4 v1.16 SIH measured here: 100 % (16.20 V), fix type 3, 10 sats, flags 0x3ff
        assert all(rows[k].endswith(" GO") for k in ("battery", "GPS", "EKF", "home")), rows
        mav.set_param_int("COM_OBL_RC_ACT", 5)
        assert run(30.0, until=lambda: mav.params.get("COM_OBL_RC_ACT") == 5)
        run(11.0)  # the bridge's parameter refresh (10 s)
        ref["v"] = [0.0, 0.0, 0.0]
        run(1.0)
        ok, why, out = rt.start(time.monotonic())
        mav.out(out)
        assert ok, why
        assert run(90.0, until=lambda: state() in ("OFFBOARD_ACTIVE", "FAILED", "DONE"))
        assert state() == "OFFBOARD_ACTIVE", (mav.log[-10:], mav.modes)
        assert ("OFFBOARD", True) in mav.modes  # PX4's own report: OFFBOARD, armed
        z0 = mav.z[-1]
        ref["v"] = [0.0, 0.0, -1.5]  # FRD: up
        run(30.0, until=lambda: mav.z[-1] < z0 - 3.0)
        ref["v"] = [0.0, 0.0, 0.0]
        run(2.0)
        z_climbed = mav.z[-1]
        assert z_climbed < z0 - 2.0, (z0, z_climbed)
        mav.out(rt.abort(time.monotonic(), "end of test")[2])
        ref["v"] = None
        assert run(90.0, until=lambda: state() in ("DONE", "FAILED"))
        run(2.0)
    reason = rt.core.status(0.0)["reason"]
    print(
        "MAVROS stand-in on PX4:",
        mav.modes,
        mav.acks,
        f"z0={z0:.2f} climbed={z_climbed:.2f} end={mav.z[-1]:.2f}",
        reason,
    )
    assert state() == "DONE", (reason, mav.log[-10:])
    assert reason.startswith("hand-back confirmed: vehicle in HOLD after POSCTL"), reason
    names = [m for m, _ in mav.modes]
    assert "POSCTL" not in names and names[-1] == "AUTO.LOITER", mav.modes
    # PX4 refused POSCTL (176 TEMPORARILY_REJECTED): visible here, never to MAVROS's set_mode
    assert (176, px4.MAV_RESULT_TEMPORARILY_REJECTED) in mav.acks
    assert abs(mav.z[-1] - z_climbed) < 1.5  # held altitude: no offboard-loss descent


def test_px4_sitl_stale_mavros_state_hands_back_and_confirms_nothing():
    """MAVROS's state stalls during OFFBOARD (the stand-in stops forwarding HEARTBEATs as
    State for longer than state_timeout): the bridge hands back, PX4 applies HOLD (its
    HEARTBEAT, seen by the stand-in), but with no State nothing is confirmed: FAILED, level
    error, never DONE. Preflight off (COM_OBL_RC_ACT left at PX4's default)."""
    defaults = {n: d for n, (d, _) in SPECS.items()}
    params = {
        **defaults,
        "transport": "mavros",
        "mavros.interfaces": "mavros_msgs",
        "mavros.preflight": False,
        "mavros.state_timeout": 2.0,
        "command": "velocity",
        "offboard.arm": True,
        "offboard.handback_chain": ["HOLD", "LAND"],
        "offboard.mode_confirm_timeout": 3.0,
        "offboard.ack_timeout": 2.0,
        "offboard.input_timeout": 1.0,
    }
    rt = BridgeRuntime(params, F, "/lpv_sysid/mavlink_bridge", 60.0, 3.0)
    with Px4Sitl(PX4_DIR, instance=INSTANCE, boot_timeout=240.0):
        mav = MavrosStandIn(URL, rt)
        forward = {"state": True}
        on_message = rt.on_message

        def gate(key, msg, now):  # MAVROS's state topic stalls
            if key == "mavros_state" and not forward["state"]:
                return []
            return on_message(key, msg, now)

        rt.on_message = gate  # type: ignore[method-assign]

        def run(seconds, v=None, until=None):
            end = time.monotonic() + seconds
            next_ref = 0.0
            while time.monotonic() < end:
                now = time.monotonic()
                mav.pump(now)
                if v is not None and now >= next_ref:
                    next_ref = now + 0.05
                    msg = messages.twist_reference_msg(F, round(now * 1e9), v, 0.0)
                    mav.out(
                        rt.on_sample("velocity_reference", PARSERS["velocity_reference"](msg), now)
                    )
                mav.out(rt.on_timer(now))
                if until is not None and until():
                    return True
                time.sleep(0.004)
            return False

        state = lambda: rt.core.state.value  # noqa: E731
        assert run(90.0, until=lambda: bool(mav.z))
        run(2.0, v=[0.0, 0.0, 0.0])
        ok, why, out = rt.start(time.monotonic())
        mav.out(out)
        assert ok, why
        assert run(
            90.0, v=[0.0, 0.0, -1.0], until=lambda: state() in ("OFFBOARD_ACTIVE", "FAILED")
        )
        assert state() == "OFFBOARD_ACTIVE", mav.log[-10:]
        run(4.0, v=[0.0, 0.0, -1.0])
        forward["state"] = False
        assert run(10.0, v=[0.0, 0.0, 0.0], until=lambda: state() == "HANDBACK")
        assert run(60.0, until=lambda: state() in ("DONE", "FAILED"))
        names = [m for m, _ in mav.modes]
    reason = rt.core.status(0.0)["reason"]
    print("stale MAVROS state on PX4:", mav.modes, reason)
    assert "AUTO.LOITER" in names  # PX4 did switch to HOLD: the bridge could not know
    assert state() == "FAILED" and reason.startswith("hand-back NOT confirmed"), reason
    assert any("no /mavros/state for" in t for _, t in mav.log), mav.log[-10:]


def test_px4_sitl_rate_setpoints_through_mavros_attitude_target_turn_the_right_way():
    """Phase 2's command path (``command: rate_setpoint``, setpoint_raw/attitude): PX4 flies
    the body rates it receives. A yaw-rate setpoint r_sp = +0.6 rad/s (FRD: clockwise seen
    from above) with thrust above hover must make PX4's own NED yaw grow and the vehicle
    rise -- a sign error in the FRD <-> FLU conversion (bridge or MAVROS side) turns it
    the other way. Preflight off; the hand-back goes to HOLD."""
    defaults = {n: d for n, (d, _) in SPECS.items()}
    params = {
        **defaults,
        "transport": "mavros",
        "mavros.interfaces": "mavros_msgs",
        "mavros.preflight": False,
        "command": "rate_setpoint",
        "offboard.arm": True,
        "offboard.handback_chain": ["HOLD", "LAND"],
        "offboard.mode_confirm_timeout": 5.0,
        "offboard.ack_timeout": 2.0,
        "offboard.input_timeout": 1.0,
    }
    rt = BridgeRuntime(params, F, "/lpv_sysid/mavlink_bridge", 60.0, 3.0)
    u = np.array([0.7, 0.0, 0.0, 0.6])  # thrust, p_sp, q_sp, r_sp
    with Px4Sitl(PX4_DIR, instance=INSTANCE, boot_timeout=240.0):
        mav = MavrosStandIn(URL, rt)

        def run(seconds, cmd=None, until=None):
            end = time.monotonic() + seconds
            next_cmd = 0.0
            while time.monotonic() < end:
                now = time.monotonic()
                mav.pump(now)
                if cmd is not None and now >= next_cmd:
                    next_cmd = now + 0.02
                    mav.out(rt.on_sample("actuator_command", (now, cmd), now))
                mav.out(rt.on_timer(now))
                if until is not None and until():
                    return True
                time.sleep(0.004)
            return False

        state = lambda: rt.core.state.value  # noqa: E731
        assert run(90.0, until=lambda: bool(mav.z) and bool(mav.yaw))
        ok, why, out = rt.start(time.monotonic())
        mav.out(out)
        assert ok, why
        hold = np.array([0.0, 0.0, 0.0, 0.0])  # on the ground: no thrust until OFFBOARD
        assert run(90.0, cmd=hold, until=lambda: state() in ("OFFBOARD_ACTIVE", "FAILED"))
        assert state() == "OFFBOARD_ACTIVE", mav.log[-10:]
        n0, z0 = len(mav.yaw), mav.z[-1]
        run(3.0, cmd=u)
        yaw = np.unwrap(np.array(mav.yaw[n0:]))
        turned, rose = float(yaw[-1] - yaw[0]), float(z0 - mav.z[-1])
        mav.out(rt.abort(time.monotonic(), "end of test")[2])
        assert run(60.0, until=lambda: state() in ("DONE", "FAILED"))
    print(f"rate setpoints through MAVROS on PX4: yaw +{turned:.2f} rad, rose {rose:.2f} m")
    assert turned > 0.5, turned  # r_sp 0.6 rad/s for 3 s (PX4's rate loop lags)
    assert rose > 0.3, rose
    assert state() == "DONE" and "vehicle in HOLD" in rt.core.status(0.0)["reason"]
