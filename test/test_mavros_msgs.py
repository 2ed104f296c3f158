"""transport mavros with mavros_msgs: the bridge runtime against a fake MAVROS.

The fake (:class:`FakeMavros`) behaves as MAVROS 2.10's sys_status / command plugins do:
``set_mode`` answers ``mode_sent = true`` as soon as SET_MODE is sent and the mode shows on
``/mavros/state`` (1 Hz, every HEARTBEAT) only if the autopilot applies it; ``cmd/arming``
answers with PX4's COMMAND_ACK result. Oracles: the truth rule of mavlink/offboard (DONE only
when the state shows the requested mode after the final answer), MAVROS's frame conversions
(setpoint_raw plugin: FRD -> FLU is x, -y, -z; the ENU yaw rate is negated), the MAVLink
type_mask bits (velocity + yaw rate 0x07C7, ATTITUDE_IGNORE 128), seed 0 Eq. (7) inverted
by hand for the attitude_rate transport, rpm -> rad/s = 2 pi / 60.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavros_msgs.msg import VehicleInfo
from mavros_msgs.srv import (
    CommandBool,
    CommandLong,
    MessageInterval,
    ParamPull,
    SetMode,
    VehicleInfoGet,
)
from rcl_interfaces.msg import ListParametersResult, ParameterValue
from rcl_interfaces.srv import GetParameters, ListParameters

from lpv_sysid.flight.bridge import PARSERS, SPECS, BridgeRuntime
from lpv_sysid.io import messages
from lpv_sysid.mavlink import codec, px4
from lpv_sysid.mavlink.bridge import ServiceRequest

F = messages.MsgFactory.rclpy()  # the stand-in's rclpy classes (test/support), mavros_msgs too
DEFAULTS = {n: d for n, (d, _) in SPECS.items()}
ZERO3 = [0.0, 0.0, 0.0]
#: PX4 v1.16 SITL's answers to the preflight's parameter questions (Hold on offboard loss,
#: no stick input)
PX4_PARAMS = {
    "COM_OF_LOSS_T": 1.0,
    "COM_OBL_RC_ACT": 5,
    "COM_DISARM_PRFLT": 10.0,
    "NAV_DLL_ACT": 0,
    "COM_RCL_EXCEPT": 4,
    "COM_RC_IN_MODE": 4,
    # PX4 v1.16 defaults of the velocity and tilt limits (checked against a planned box)
    "MPC_XY_VEL_MAX": 12.0,
    "MPC_Z_VEL_MAX_UP": 3.0,
    "MPC_Z_VEL_MAX_DN": 1.5,
    "MPC_TILTMAX_AIR": 45.0,
}
#: a converged EKF2 with GPS as MAVROS's estimator_status shows it (ESTIMATOR_STATUS flags
#: 0x33f: attitude, velocities, relative and absolute horizontal and absolute vertical
#: position, predicted positions)
EKF_OK = (
    "attitude_status_flag",
    "velocity_horiz_status_flag",
    "velocity_vert_status_flag",
    "pos_horiz_rel_status_flag",
    "pos_horiz_abs_status_flag",
    "pos_vert_abs_status_flag",
    "pred_pos_horiz_rel_status_flag",
    "pred_pos_horiz_abs_status_flag",
)
_MOD = codec.dialect_module()
CAPS = (
    _MOD.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | _MOD.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | _MOD.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
)


BATTERY = "sensor_msgs/msg/BatteryState"
GPSRAW = "mavros_msgs/msg/GPSRAW"
ESTIMATOR = "mavros_msgs/msg/EstimatorStatus"
HOME = "mavros_msgs/msg/HomePosition"
GEOPOINT = "geographic_msgs/msg/GeoPoint"
NAVSATFIX, NAVSATSTATUS = "sensor_msgs/msg/NavSatFix", "sensor_msgs/msg/NavSatStatus"


def vehicle_info(version=(1, 16, 0)):
    return VehicleInfo(
        sysid=1,
        compid=1,
        autopilot=12,
        type=2,
        capabilities=CAPS,
        flight_sw_version=px4.encode_flight_sw_version(*version),
        available_info=3,  # HAVE_INFO_HEARTBEAT | HAVE_INFO_AUTOPILOT_VERSION, as MAVROS sets
    )


def param_answer(names, params):
    values = []
    for n in names:
        v = params.get(n)
        if v is None:
            values.append(ParameterValue(type=0))
        elif isinstance(v, int):
            values.append(ParameterValue(type=2, integer_value=v))
        else:
            values.append(ParameterValue(type=3, double_value=v))
    return GetParameters.Response(values=values)


def runtime(**overrides):
    p = {**DEFAULTS, "transport": "mavros", "mavros.interfaces": "mavros_msgs", **overrides}
    return BridgeRuntime(p, F, "/lpv_sysid/mavlink_bridge", 30.0, 3.0)


class FakeMavros:
    """MAVROS + a PX4 that applies the modes of ``applies`` (MAVROS names)."""

    def __init__(self, rt, mode="AUTO.LOITER", armed=False, applies=None):
        self.rt, self.mode, self.armed = rt, mode, armed
        self.applies = applies  # None: every mode
        self.publishing = True  # /mavros/state published (False: stale)
        self.system_status = 4  # HEARTBEAT MAV_STATE (PX4: 5 CRITICAL while in a failsafe)
        self.params = dict(PX4_PARAMS)  # what MAVROS's param node has pulled
        self.info = vehicle_info()
        self.asked: list[str] = []
        self.pulls = 0  # param/pull calls answered
        self.rates: list = []  # (t, set_message_interval request)
        self.requested: list = []  # (t, cmd/command request)
        self.rc_out = True  # publishes /mavros/rc/out (PX4 SITL: SERVO_OUTPUT_RAW)
        # the vehicle's health as MAVROS publishes it (None: topic not published)
        self.battery = 0.8  # /mavros/battery percentage (0..1; PX4's -1 comes as -0.01)
        self.gps = 3  # /mavros/gpsstatus/gps1/raw fix_type
        self.ekf: tuple[str, ...] | None = EKF_OK  # estimator_status flags set
        self.home = (47.397742, 8.545594, 488.0)  # /mavros/home_position/home geo
        self.fix: int | None = None  # /mavros/global_position/raw/fix status.status
        self.calls: list[ServiceRequest] = []
        self.sent: list[tuple[float, str, object]] = []  # (t, key, msg) setpoints
        self.events: list[tuple[float, str, str]] = []  # (t, level, text) the runtime logged
        self.t = 0.0
        self._next_state = 0.0
        self.omega = ZERO3

    def handle(self, out):
        for key, item in out:
            if isinstance(item, ServiceRequest):
                self.calls.append(item)
                if key == "set_mode":
                    name = item.fields["custom_mode"]
                    if self.applies is None or name in self.applies:
                        self.mode = name
                    resp = SetMode.Response(mode_sent=True)
                elif key == "param_get":
                    self.asked += item.fields["names"]
                    resp = param_answer(item.fields["names"], self.params)
                elif key == "param_pull":  # MAVROS' param plugin: PARAM_REQUEST_LIST
                    self.pulls += 1
                    resp = ParamPull.Response(success=True, param_received=len(self.params))
                elif key == "param_list":  # the param node: PX4's names and its own
                    names = [*self.params, "use_sim_time"] if self.pulls else []
                    resp = ListParameters.Response(result=ListParametersResult(names=names))
                elif key == "record_param_get":
                    resp = param_answer(item.fields["names"], self.params)
                elif key == "message_interval":
                    self.rates.append((self.t, dict(item.fields)))
                    resp = MessageInterval.Response(success=True)
                elif key == "vehicle_info":
                    ok = self.info is not None
                    resp = VehicleInfoGet.Response(success=ok, vehicles=[self.info] if ok else [])
                elif key == "request_message":  # cmd/command: PX4 acknowledges (and sends)
                    self.requested.append((self.t, dict(item.fields)))
                    resp = CommandLong.Response(success=True, result=0)
                else:
                    self.armed = bool(item.fields["value"])
                    resp = CommandBool.Response(success=True, result=0)
                self.handle(self.rt.on_service_answer(item, resp, self.t))
            elif key == "status":
                self.events += [(self.t, lv, text) for lv, text in self.rt.take_log()]
            else:
                self.sent.append((self.t, key, item))

    def state_msg(self, connected=True, mode=None):
        return F(
            "mavros_msgs/msg/State",
            header=messages.header_msg(F, round(self.t * 1e9)),
            connected=connected,
            armed=self.armed,
            mode=self.mode if mode is None else mode,
            system_status=self.system_status,
        )

    def health_msgs(self):
        """``(key, topic under /mavros, message)`` of the health topics as MAVROS 2.10
        fills them (1 Hz here)."""
        h = messages.header_msg(F, round(self.t * 1e9))
        out = []
        if self.battery is not None:
            pct = float(np.float32(self.battery))  # MAVROS: battery_remaining / 100.0f
            msg = F(BATTERY, header=h, voltage=16.2, percentage=pct)
            out.append(("mavros_battery", "battery", msg))
        if self.gps is not None:
            sats = 10 if self.gps >= 3 else 2
            msg = F(GPSRAW, header=h, fix_type=self.gps, satellites_visible=sats)
            out.append(("mavros_gps_raw", "gpsstatus/gps1/raw", msg))
        if self.fix is not None:
            msg = F(NAVSATFIX, header=h, status=F(NAVSATSTATUS, status=self.fix, service=1))
            out.append(("mavros_gps_fix", "global_position/raw/fix", msg))
        if self.ekf is not None:
            msg = F(ESTIMATOR, header=h, **dict.fromkeys(self.ekf, True))
            out.append(("mavros_estimator", "estimator_status", msg))
        if self.home is not None:
            lat, lon, alt = self.home
            geo = F(GEOPOINT, latitude=lat, longitude=lon, altitude=alt)
            out.append(("mavros_home", "home_position/home", F(HOME, header=h, geo=geo)))
        return out

    def run(self, seconds, reference=None, actuator=None, dt=0.004):
        """Advance: 1 Hz state, 50 Hz odometry, 250 Hz poll, the commands at 50 Hz."""
        end = self.t + seconds
        k = 0
        while self.t < end - 1e-9:
            self.t = round(self.t + dt, 6)
            k += 1
            if self.publishing and self.t >= self._next_state:
                self._next_state = self.t + 1.0
                self.handle(self.rt.on_message("mavros_state", self.state_msg(), self.t))
                for key, _, msg in self.health_msgs():
                    self.handle(self.rt.on_message(key, msg, self.t))
            if k % 5 == 0:
                odom = messages.odometry_from_state(
                    F,
                    round(self.t * 1e9),
                    [0.0, 0.0, -5.0],
                    ZERO3,
                    ZERO3,
                    self.omega,
                    frame_id="map",
                )
                self.handle(self.rt.on_message("mavros_odom", odom, self.t))
                if self.rc_out and k % 25 == 0:  # PX4 SITL's SERVO_OUTPUT_RAW, 10 Hz
                    rc = F(
                        "mavros_msgs/msg/RCOut",
                        header=messages.header_msg(F, round(self.t * 1e9)),
                        channels=[1500 if self.armed else 900] * 4,
                    )
                    self.handle(self.rt.on_message("mavros_rc_out", rc, self.t))
                if reference is not None:
                    msg = messages.twist_reference_msg(F, round(self.t * 1e9), *reference)
                    parsed = PARSERS["velocity_reference"](msg)
                    self.handle(self.rt.on_sample("velocity_reference", parsed, self.t))
                if actuator is not None:
                    self.handle(
                        self.rt.on_sample(
                            "actuator_command", (self.t, np.asarray(actuator)), self.t
                        )
                    )
            self.handle(self.rt.on_timer(self.t))

    def state(self):
        return self.rt.core.state.value

    def setpoints(self, key):
        return [m for _, k, m in self.sent if k == key]

    def mode_calls(self):
        return [(c.key, c.fields) for c in self.calls if c.key in ("set_mode", "arming")]

    def modes_requested(self):
        return [c.fields["custom_mode"] for c in self.calls if c.key == "set_mode"]


def started(fake, **kw):
    fake.run(0.5, **kw)  # telemetry and state before start
    ok, message, out = fake.rt.start(fake.t)
    fake.handle(out)
    assert ok, message
    return fake


def test_endpoints_of_the_mavros_msgs_mode():
    rt = runtime(command="velocity")
    pubs = {e.key: (e.topic, e.typename) for e in rt.publishers}
    assert pubs["mavros_local"] == ("/mavros/setpoint_raw/local", "mavros_msgs/msg/PositionTarget")
    assert "mavros_attitude" not in pubs
    # PX4's ATTITUDE_TARGET as MAVROS republishes it: the rate_setpoint echo
    assert "rate_setpoint" in pubs
    subs_ = {e.key: (e.topic, e.typename) for e in rt.subscriptions}
    assert subs_["mavros_target_attitude"] == (
        "/mavros/setpoint_raw/target_attitude",
        "mavros_msgs/msg/AttitudeTarget",
    )
    subs = {e.key: (e.topic, e.typename) for e in rt.subscriptions}
    assert subs["mavros_state"] == ("/mavros/state", "mavros_msgs/msg/State")
    assert subs["mavros_esc"] == ("/mavros/esc_status/status", "mavros_msgs/msg/ESCStatus")
    assert subs["mavros_rc_out"] == ("/mavros/rc/out", "mavros_msgs/msg/RCOut")
    assert subs["mavros_rc_in"] == ("/mavros/rc/in", "mavros_msgs/msg/RCIn")
    # the vehicle's health (MAVROS 2.10 sys_status, gps_status, global_position plugins)
    assert subs["mavros_home"] == ("/mavros/home_position/home", HOME)
    assert subs["mavros_battery"] == ("/mavros/battery", BATTERY)
    assert subs["mavros_gps_raw"] == ("/mavros/gpsstatus/gps1/raw", GPSRAW)
    assert subs["mavros_gps_fix"] == ("/mavros/global_position/raw/fix", NAVSATFIX)
    assert subs["mavros_estimator"] == ("/mavros/estimator_status", ESTIMATOR)
    assert [(e.key, e.topic, e.typename) for e in rt.clients] == [
        ("set_mode", "/mavros/set_mode", "mavros_msgs/srv/SetMode"),
        ("arming", "/mavros/cmd/arming", "mavros_msgs/srv/CommandBool"),
        ("message_interval", "/mavros/set_message_interval", "mavros_msgs/srv/MessageInterval"),
        ("param_pull", "/mavros/param/pull", "mavros_msgs/srv/ParamPull"),
        ("param_list", "/mavros/param/list_parameters", "rcl_interfaces/srv/ListParameters"),
        ("record_param_get", "/mavros/param/get_parameters", "rcl_interfaces/srv/GetParameters"),
        ("vehicle_info", "/mavros/vehicle_info_get", "mavros_msgs/srv/VehicleInfoGet"),
        ("param_get", "/mavros/param/get_parameters", "rcl_interfaces/srv/GetParameters"),
        ("request_message", "/mavros/cmd/command", "mavros_msgs/srv/CommandLong"),
    ]
    rt = runtime(
        command="velocity",
        rate_setpoints=False,
        **{"mavros.preflight": False, "mavros.rc_out_rate_hz": 0.0},
    )
    # the vehicle record's questions and its battery stay without the preflight
    assert [e.key for e in rt.clients] == [
        "set_mode",
        "arming",
        "param_pull",
        "param_list",
        "record_param_get",
        "vehicle_info",
    ]
    keys = {e.key for e in rt.subscriptions}
    assert "mavros_battery" in keys and not {"mavros_rc_in", "mavros_estimator"} & keys
    rt = runtime(command="attitude_rate", **{"mavros.namespace": "/uav1/mavros"})
    pubs = {e.key: e.topic for e in rt.publishers}
    assert pubs["mavros_attitude"] == "/uav1/mavros/setpoint_raw/attitude"
    assert "mavros_local" not in pubs
    # phase 1 takes velocity_reference; phase 2's is the controller's input (not subscribed:
    # real MAVROS phase 2 logged an ERROR for each, 50 a second)
    assert "velocity_reference" in {e.key for e in runtime(command="velocity").subscriptions}
    for command in ("attitude_rate", "rate_setpoint"):
        keys = {e.key for e in runtime(command=command).subscriptions}
        assert "velocity_reference" not in keys and "actuator_command" in keys, command


def test_offboard_arm_run_and_handback_confirmed_through_mavros_state():
    rt = runtime(command="velocity", **{"offboard.arm": True})
    fake = started(FakeMavros(rt))
    fake.run(6.0, reference=([1.0, 0.5, -0.2], 0.3))
    assert fake.state() == "OFFBOARD_ACTIVE"
    assert fake.mode_calls() == [
        ("set_mode", {"base_mode": 0, "custom_mode": "OFFBOARD"}),
        ("arming", {"value": True}),
    ]
    assert fake.mode == "OFFBOARD" and fake.armed
    # the setpoint: BODY_NED, velocity + yaw rate, FLU body velocity, ENU yaw rate
    sp = fake.setpoints("mavros_local")[-1]
    assert sp.coordinate_frame == 8 and sp.type_mask == 0x07C7
    # position, acceleration/force (FORCE bit too) and yaw ignored: velocity + yaw rate used
    assert sp.type_mask == (1 | 2 | 4 | 64 | 128 | 256 | 512 | 1024)
    np.testing.assert_allclose([sp.velocity.x, sp.velocity.y, sp.velocity.z], [1.0, -0.5, 0.2])
    # r_d FRD = 0.3 (down axis) is the ENU yaw rate -0.3 MAVROS negates again
    assert sp.yaw_rate == pytest.approx(-0.3)
    v, r = messages.velocity_setpoint_from_position_target(sp)[2:]
    np.testing.assert_allclose(v, [1.0, 0.5, -0.2])  # what MAVROS hands PX4 (FRD)
    assert r == pytest.approx(0.3)
    # hand-back: HOLD requested, DONE only once /mavros/state shows AUTO.LOITER
    ok, _, out = rt.abort(fake.t)
    fake.handle(out)
    assert fake.state() == "HANDBACK"
    fake.run(3.0)
    assert fake.state() == "DONE" and fake.modes_requested()[-1] == "AUTO.LOITER"
    assert "hand-back confirmed: vehicle in HOLD" in rt.core.status(fake.t)["reason"]


def test_a_mode_mavros_sent_but_px4_never_showed_is_not_confirmed():
    rt = runtime(command="velocity")
    fake = started(FakeMavros(rt, applies={"OFFBOARD", "AUTO.LAND"}))
    fake.run(4.0, reference=([0.5, 0.0, 0.0], 0.0))
    assert fake.state() == "OFFBOARD_ACTIVE"
    fake.handle(rt.abort(fake.t)[2])
    fake.run(2.0)
    # HOLD was sent (mode_sent true) but never shown: no DONE while waiting
    assert fake.state() == "HANDBACK" and fake.mode == "OFFBOARD"
    fake.run(5.0)
    assert fake.modes_requested()[-2:] == ["AUTO.LOITER", "AUTO.LAND"]
    assert fake.state() == "DONE"
    reason = rt.core.status(fake.t)["reason"]
    assert "vehicle in LAND after HOLD" in reason and "did not show it" in reason


def test_rejected_handback_chain_ends_failed_never_done():
    rt = runtime(command="velocity")
    fake = started(FakeMavros(rt, applies={"OFFBOARD"}))
    fake.run(4.0, reference=([0.5, 0.0, 0.0], 0.0))
    assert fake.state() == "OFFBOARD_ACTIVE"
    fake.handle(rt.abort(fake.t)[2])
    fake.run(10.0)
    assert fake.state() == "FAILED"
    assert fake.mode == "OFFBOARD"
    assert fake.modes_requested() == ["OFFBOARD", "AUTO.LOITER", "AUTO.LAND"]
    assert all(s != "DONE" for s in (e[2] for e in fake.events))
    last = [e for e in fake.events if e[1] == "error"][-1]
    assert "hand-back NOT confirmed" in last[2]


def test_stale_or_disconnected_state_is_no_evidence():
    rt = runtime(command="velocity", **{"mavros.state_timeout": 2.0})
    fake = started(FakeMavros(rt))
    fake.run(4.0, reference=([0.5, 0.0, 0.0], 0.0))
    assert fake.state() == "OFFBOARD_ACTIVE"
    fake.publishing = False  # MAVROS / its state topic stalls
    fake.run(1.5, reference=([0.5, 0.0, 0.0], 0.0))
    assert fake.state() == "OFFBOARD_ACTIVE"  # within state_timeout
    fake.run(1.0, reference=([0.5, 0.0, 0.0], 0.0))
    assert fake.state() == "HANDBACK"  # link down: hand back
    assert any("no /mavros/state for" in e[2] for e in fake.events)
    # PX4 applies HOLD (the fake sets it) but no State arrives; one with connected=false
    # showing AUTO.LOITER is no evidence either
    fake.handle(rt.on_message("mavros_state", fake.state_msg(connected=False), fake.t))
    fake.run(12.0)
    assert fake.modes_requested()[-2:] == ["AUTO.LOITER", "AUTO.LAND"]
    assert fake.mode == "AUTO.LAND"  # applied by PX4, never shown on /mavros/state
    # SERVO_OUTPUT_RAW (36) and ATTITUDE_TARGET (83) at 50 Hz asked once after connecting
    # (answered success), not during the stale time; again once states come back (PX4 may
    # have rebooted)
    want = [{"message_id": 36, "message_rate": 50.0}, {"message_id": 83, "message_rate": 50.0}]
    assert [r for _, r in fake.rates] == want
    fake.publishing = True
    fake.run(1.5)
    assert [r for _, r in fake.rates] == want + want
    assert fake.state() == "FAILED"
    assert "hand-back NOT confirmed" in rt.core.status(fake.t)["reason"]


def test_phase2_attitude_target_fields_from_the_actuator_command():
    # seed 0 Eq. (7) inverted (transport docstring): tau = (ua/(4s), ue/(4s), ur/4),
    # omega_sp = omega + tau / K_p with s = l sqrt(2)/2
    rt = runtime(command="attitude_rate", arm_length=0.25, rate_p=[0.2, 0.25, 0.4])
    fake = FakeMavros(rt)
    fake.omega = [0.1, -0.2, 0.05]  # FRD body rates of the odometry
    u = [0.55, 0.02, -0.03, 0.004]
    started(fake, actuator=u)
    fake.run(4.0, actuator=u)
    assert fake.state() == "OFFBOARD_ACTIVE"
    sp = fake.setpoints("mavros_attitude")[-1]
    assert sp.type_mask == 128  # attitude ignored, rates and thrust used
    s = 0.25 * math.sqrt(2.0) / 2.0
    w_frd = np.array(
        [0.1 + 0.02 / (4 * s) / 0.2, -0.2 - 0.03 / (4 * s) / 0.25, 0.05 + 0.001 / 0.4]
    )
    np.testing.assert_allclose(
        [sp.body_rate.x, sp.body_rate.y, sp.body_rate.z], w_frd * [1, -1, -1], atol=1e-9
    )
    assert sp.thrust == pytest.approx(0.55, abs=1e-6)
    assert (sp.orientation.w, sp.orientation.x) == (1.0, 0.0)
    assert not fake.setpoints("mavros_local")
    # commands stop: the last one streams for input_timeout (0.5 s at 20 Hz), then stale
    # input hands back and nothing is streamed (attitude_rate has no neutral setpoint)
    n = len(fake.setpoints("mavros_attitude"))
    fake.run(3.0)
    assert fake.state() == "FAILED" and fake.mode == "AUTO.LOITER"
    assert "hand-back confirmed: vehicle in HOLD" in rt.core.status(fake.t)["reason"]
    extra = fake.setpoints("mavros_attitude")[n:]
    assert 1 <= len(extra) <= 0.5 * 20 + 1 and all(m.thrust == sp.thrust for m in extra)


def test_rotor_speeds_from_esc_status_rpm():
    rt = runtime(command="velocity", n_rotors=4)
    fake = FakeMavros(rt)
    fake.run(0.3)
    esc = F(
        "mavros_msgs/msg/ESCStatus",
        header=messages.header_msg(F, round(fake.t * 1e9)),
        esc_status=[F("mavros_msgs/msg/ESCStatusItem", rpm=r) for r in (6000, 6100, 5900, 6050)],
    )
    fake.handle(rt.on_message("mavros_esc", esc, fake.t))
    fake.run(0.01)
    rotor = fake.setpoints("rotor_speeds")  # the package topic, collected like a setpoint
    assert rotor, "no rotor_speeds published"
    w = np.asarray(rotor[-1].velocity)
    np.testing.assert_allclose(w, np.array([6000, 6100, 5900, 6050]) * 2 * math.pi / 60)
    assert messages.rotor_source_of(rotor[-1]) == "esc"


def test_rotor_speeds_estimated_from_rc_out_pwm():
    """No ESC telemetry: /mavros/rc/out (PX4's SERVO_OUTPUT_RAW) through the motor model of
    seed 0 Eq. (8). The first sample starts at the steady state Omega = b u / a with
    u = (PWM - PWM_MAIN_MIN) / (PWM_MAIN_MAX - PWM_MAIN_MIN), here 1100 .. 1900 us."""
    rt = runtime(
        command="velocity",
        **{
            "rotor_estimate.output_min": 1100.0,
            "rotor_estimate.output_max": 1900.0,
            "rotor_estimate.a_omega": 10.0,
            "rotor_estimate.b_omega": 10000.0,
            "rotor_estimate.omega_min": 50.0,
            "rotor_estimate.omega_max": 900.0,
        },
    )
    fake = FakeMavros(rt)
    fake.rc_out = False
    fake.run(0.3)
    pwm = [1500, 1580, 1100, 1900, 1234, 900]  # channels 5, 6: not motors
    rc = F(
        "mavros_msgs/msg/RCOut",
        header=messages.header_msg(F, round(fake.t * 1e9)),
        channels=pwm,
    )
    fake.handle(rt.on_message("mavros_rc_out", rc, fake.t))
    fake.run(0.01)
    (msg,) = fake.setpoints("rotor_speeds")
    u = (np.array(pwm[:4]) - 1100.0) / 800.0
    np.testing.assert_allclose(
        np.asarray(msg.velocity), np.clip(1000.0 * u, 50.0, 900.0), rtol=1e-12
    )
    assert messages.rotor_source_of(msg) == "estimated"


def test_unknown_mode_and_bad_state_message_are_counted():
    rt = runtime(command="velocity")
    fake = FakeMavros(rt, mode="AUTO.PRECLAND")
    fake.run(1.1)
    st = rt.core.status(fake.t)
    assert st["vehicle_mode"].startswith("UNKNOWN") and st["link_unknown_modes"] != "0"
    out = rt.status(fake.t)
    _, (s,) = messages.status_from_diagnostic_array(out[0][1])
    assert s.values["mavros_mode"] == "AUTO.PRECLAND"


# ------------------------------------------------------------------- node over the stand-in
@pytest.fixture
def fresh():
    import rclpy._standin as standin

    standin.reset()
    yield
    import rclpy

    rclpy.try_shutdown()


def test_node_offboard_and_handback_with_a_fake_mavros_node(fresh):
    """The node shell: mavros_msgs types by name, the service clients, /mavros/state, the
    preflight through MAVROS's param node and vehicle_info_get (the first start is refused
    while the vehicle info is unanswered). The fake MAVROS node applies every mode but
    LOITER: the chain goes on to LAND."""
    import os

    import rclpy
    from geometry_msgs.msg import TwistStamped
    from mavros_msgs.msg import PositionTarget, RCOut, State
    from nav_msgs.msg import Odometry
    from rclpy._standin import call_trigger, spin_nodes
    from rclpy.qos import qos_profile_sensor_data

    from lpv_sysid.nodes.mavlink_bridge_node import MavlinkBridgeNode

    cfg = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "config")
    args = ["node", "--ros-args", "--params-file", f"{cfg}/mavlink_bridge_node.yaml"]
    pairs = (
        ("transport", "mavros"),
        ("mavros.interfaces", "mavros_msgs"),
        ("offboard.arm", "true"),
    )
    for k, v in pairs:
        args += ["-p", f"{k}:={v}"]
    rclpy.init(args=args)
    node = MavlinkBridgeNode(namespace="lpv_sysid")
    mavros = rclpy.create_node("mavros")
    now_ns = lambda: mavros.get_clock().now().nanoseconds  # noqa: E731
    vehicle = {"mode": "AUTO.LOITER", "armed": False, "info": False}
    calls = []

    def set_mode(req, resp):
        calls.append(req.custom_mode)
        if req.custom_mode != "AUTO.LOITER":
            vehicle["mode"] = req.custom_mode
        resp.mode_sent = True
        return resp

    def arming(req, resp):
        vehicle["armed"] = req.value
        resp.success, resp.result = True, 0
        return resp

    def get_parameters(req, resp):
        resp.values = param_answer(req.names, PX4_PARAMS).values
        return resp

    def info(req, resp):
        resp.success = vehicle["info"]
        resp.vehicles = [vehicle_info()] if vehicle["info"] else []
        return resp

    def interval(req, resp):
        rates.append((req.message_id, req.message_rate))
        resp.success = True
        return resp

    rates = []
    mavros.create_service(MessageInterval, "/mavros/set_message_interval", interval)
    mavros.create_service(GetParameters, "/mavros/param/get_parameters", get_parameters)
    mavros.create_service(VehicleInfoGet, "/mavros/vehicle_info_get", info)
    pub_rc = mavros.create_publisher(RCOut, "/mavros/rc/out", qos_profile_sensor_data)
    mavros.create_timer(
        0.1,
        lambda: pub_rc.publish(
            RCOut(
                header=messages.header_msg(F, now_ns()),
                channels=[1500 if vehicle["armed"] else 900] * 4,
            )
        ),
    )
    mavros.create_service(SetMode, "/mavros/set_mode", set_mode)
    mavros.create_service(CommandBool, "/mavros/cmd/arming", arming)
    pub_state = mavros.create_publisher(State, "/mavros/state", 10)
    # the vehicle's health on MAVROS's topics (the fake's messages, at 1 Hz)
    health = FakeMavros(None)
    health_pubs = {
        key: mavros.create_publisher(type(msg), f"/mavros/{topic}", qos_profile_sensor_data)
        for key, topic, msg in health.health_msgs()
    }
    mavros.create_timer(
        1.0, lambda: [health_pubs[k].publish(m) for k, _, m in health.health_msgs()]
    )
    pub_odom = mavros.create_publisher(
        Odometry, "/mavros/local_position/odom", qos_profile_sensor_data
    )
    mavros.create_timer(
        1.0,
        lambda: pub_state.publish(
            State(
                header=messages.header_msg(F, now_ns()),
                connected=True,
                armed=vehicle["armed"],
                mode=vehicle["mode"],
            )
        ),
    )
    mavros.create_timer(
        0.02,
        lambda: pub_odom.publish(
            messages.odometry_from_state(
                F, now_ns(), [0.0, 0.0, -5.0], ZERO3, ZERO3, ZERO3, frame_id="map"
            )
        ),
    )
    sp = []
    mavros.create_subscription(PositionTarget, "/mavros/setpoint_raw/local", sp.append, 10)
    pub_ref = mavros.create_publisher(TwistStamped, "/lpv_sysid/velocity_reference", 10)
    ref = mavros.create_timer(
        0.02,
        lambda: pub_ref.publish(messages.twist_reference_msg(F, now_ns(), [0.4, 0.0, 0.0], 0.0)),
    )
    try:
        spin_nodes([node, mavros], 3.0)
        r = call_trigger(mavros, [node], "/lpv_sysid/mavlink_bridge/start")
        assert not r.success and "vehicle info: no answer" in r.message, r.message
        assert node.core.state.value == "IDLE" and calls == []
        vehicle["info"] = True  # MAVROS got AUTOPILOT_VERSION
        spin_nodes([node, mavros], 3.0)
        r = call_trigger(mavros, [node], "/lpv_sysid/mavlink_bridge/start")
        assert r.success, r.message
        spin_nodes([node, mavros], 5.0)
        assert node.core.state.value == "OFFBOARD_ACTIVE" and vehicle["mode"] == "OFFBOARD"
        assert vehicle["armed"]
        last = sp[-1]
        assert (last.coordinate_frame, last.type_mask) == (8, 0x07C7)
        assert (last.velocity.x, last.velocity.y, last.velocity.z) == (0.4, 0.0, 0.0)
        mavros.destroy_timer(ref)  # the reference stops: stale input -> hand-back
        spin_nodes([node, mavros], 8.0)
    finally:
        node.destroy_node()
    assert calls == ["OFFBOARD", "AUTO.LOITER", "AUTO.LAND"]
    assert rates == [(36, 50.0), (83, 50.0)]
    assert node.core.state.value == "FAILED" and vehicle["mode"] == "AUTO.LAND"
    assert "vehicle in LAND after HOLD" in node.core.status(0.0)["reason"]


# ----------------------------------------------------------------- preflight through MAVROS
def preflight_start(fake):
    fake.run(1.0)
    ok, message, out = fake.rt.start(fake.t)
    fake.handle(out)
    fake.run(2.0)
    return ok, message


@pytest.mark.parametrize(
    "change, named",
    [
        # Position on offboard loss without stick input (COM_RC_IN_MODE 4): PX4 descends
        ({"params": {"COM_OBL_RC_ACT": 0}}, "COM_OBL_RC_ACT: 0 (POSITION)"),
        ({"params": {"COM_OF_LOSS_T": 5.0}}, "COM_OF_LOSS_T: 5 s"),
        ({"params": {"COM_OF_LOSS_T": None}}, "COM_OF_LOSS_T: missing"),  # not pulled yet
        ({"info": vehicle_info((1, 13, 0))}, "firmware: 1.13.0"),
        ({"info": None}, "vehicle info: no answer"),
        ({"rc_out": False}, "rotor speeds: none"),
        # the vehicle's health through MAVROS's topics (same rules as over MAVLink)
        ({"battery": 0.24}, "battery: 24 % (16.20 V)"),  # below the 25 % reserve
        ({"battery": -0.01}, "battery: unknown"),  # PX4's -1 as MAVROS divides it
        ({"battery": float("nan")}, "battery: unknown"),
        ({"battery": None}, "battery: unknown"),  # /mavros/battery not published
        # no GPS fix and no horizontal position in the EKF (no vision / flow either)
        ({"gps": 1, "ekf": EKF_OK[:3] + EKF_OK[5:6]}, "GPS: fix type 1 (no 3D fix)"),
        ({"gps": None, "fix": -1, "ekf": EKF_OK[:3]}, "GPS: fix type 1 (no 3D fix)"),
        # flags 0x33d: horizontal velocity (0x2) missing
        ({"ekf": EKF_OK[:1] + EKF_OK[2:]}, "EKF: flags 0x33d"),
        ({"ekf": EKF_OK + ("accel_error_status_flag",)}, "EKF: flags 0xb3f"),
        ({"ekf": None}, "EKF: no ESTIMATOR_STATUS"),
        ({"home": None}, "home position: not set"),
    ],
)
def test_preflight_no_go_refuses_start_before_any_mode_command(change, named):
    rt = runtime(command="velocity")
    fake = FakeMavros(rt)
    for k, v in change.items():
        if k == "params":
            for p, x in v.items():
                if x is None:
                    fake.params.pop(p)
                else:
                    fake.params[p] = x
        else:
            setattr(fake, k, v)
    ok, message = preflight_start(fake)
    assert not ok and message.startswith("start refused: preflight NO-GO through MAVROS")
    assert named in message, message
    assert fake.state() == "IDLE" and fake.mode_calls() == []
    assert not fake.setpoints("mavros_local")
    table = [t for _, lv, t in fake.events if t.startswith("preflight (MAVROS)")]
    assert table and "NO-GO" in table[-1]


def test_an_armed_vehicle_is_no_reason_to_refuse_the_start():
    """Phase 2 takes an airborne vehicle (armed, in Hold): the ground check 'armed' of the
    CLI preflight is shown, not blocking; a vehicle armed in OFFBOARD still is (another
    controller flies it)."""
    rt = runtime(command="velocity")
    fake = FakeMavros(rt, mode="AUTO.LOITER", armed=True)
    ok, message = preflight_start(fake)
    assert ok, message
    table = [t for _, lv, t in fake.events if t.startswith("preflight (MAVROS)")][-1]
    assert [x for x in table.splitlines() if x.startswith("armed")][0].endswith("NO-GO")
    rt = runtime(command="velocity")
    fake = FakeMavros(rt, mode="OFFBOARD", armed=True)
    ok, message = preflight_start(fake)
    assert not ok and "mode: OFFBOARD (armed)" in message and "armed: armed" not in message


def test_a_parameter_fixed_after_a_refusal_counts_at_the_next_start():
    rt = runtime(command="velocity")
    fake = FakeMavros(rt)
    fake.params["COM_OBL_RC_ACT"] = 0
    ok, message = preflight_start(fake)
    assert not ok and "COM_OBL_RC_ACT: 0 (POSITION)" in message
    # a judged NO-GO: nothing named missing (test_mavros_real's start retry stops on it)
    assert "missing" not in message, message
    fake.params["COM_OBL_RC_ACT"] = 5  # `ros2 param set /mavros/param COM_OBL_RC_ACT 5`
    fake.run(10.5)  # the parameters are refreshed every 10 s
    fake.run(1.0)
    ok, message, out = rt.start(fake.t)
    fake.handle(out)
    assert ok, message
    fake.run(3.0, reference=([0.5, 0.0, 0.0], 0.0))
    assert fake.state() == "OFFBOARD_ACTIVE"
    assert fake.mode_calls() == [("set_mode", {"base_mode": 0, "custom_mode": "OFFBOARD"})]


def test_state_is_stamped_with_mavros_stamp_whatever_the_bridge_latency():
    """MAVROS stamps local_position/odom with ROS time -- the bridge's clock: the state
    keeps that stamp (the sample's time; the loop delay the controller measures starts
    there), whether the bridge reads it 200 ms late (stalled) or at once; stamps never step
    back. Through PX4's boot-time envelope the stalled run raised the stamps (the age
    under-stated) and the first prompt sample stepped back (the controller's out_of_order
    abort, measured in the real phase-2 graph at load 15)."""
    rt = runtime(command="rate_setpoint")
    fake = FakeMavros(rt)
    fake.run(0.5)
    t0, stamps, got = fake.t + 1.0, [], []
    for k in range(60):
        t = t0 + k / 30.0  # MAVROS's stamp (ROS time), 30 Hz
        now = t + (0.2 if 10 <= k < 30 else 0.001)
        odom = messages.odometry_from_state(
            F, round(t * 1e9), [0.0, 0.0, -5.0], ZERO3, ZERO3, ZERO3, frame_id="map"
        )
        stamps.append(round(t * 1e9))
        rt.on_message("mavros_odom", odom, now)
        got += [messages.stamp_ns_of(m) for k_, m in rt.on_timer(now) if k_ == "state"]
    # the stamp to the microsecond (MavrosLink carries MAVLink's time_usec)
    assert len(got) == len(stamps) and all(0 <= s - g < 1000 for s, g in zip(stamps, got))


def test_firmware_answered_before_mavros_had_autopilot_version_is_asked_until_known():
    """MAVROS answers vehicle_info_get from PX4's HEARTBEAT before it has PX4's
    AUTOPILOT_VERSION (``flight_sw_version`` 0; MAVROS 2.10 requests it a few times after
    connecting only, which a stalled host can miss for good): the start is refused with the
    firmware named as missing evidence; the bridge keeps asking vehicle_info_get and asks
    PX4 through cmd/command (MAV_CMD_REQUEST_MESSAGE 512, param1 148 = AUTOPILOT_VERSION),
    one call per ask period; once MAVROS answers PX4 1.16.0 the next start is GO and
    nothing more is requested."""
    rt = runtime(command="velocity")
    fake = FakeMavros(rt)
    # MAVROS's VehicleInfo from the HEARTBEAT alone (available_info HAVE_INFO_HEARTBEAT)
    fake.info = VehicleInfo(sysid=1, compid=1, autopilot=12, type=2, available_info=1)
    ok, message = preflight_start(fake)
    assert not ok and message.startswith("start refused: preflight NO-GO through MAVROS")
    assert "firmware: no AUTOPILOT_VERSION" in message, message
    assert message.endswith("evidence missing so far: firmware"), message
    fake.run(5.0)
    infos = [c for c in fake.calls if c.key == "vehicle_info"]
    # asked every 2 s while unknown (the old bridge kept the first answer: asked once)
    assert len(infos) >= 4, len(infos)
    want = {"broadcast": False, "command": 512, "confirmation": 0, "param1": 148.0}
    assert fake.requested and all(f == want for _, f in fake.requested), fake.requested
    gaps = np.diff([t for t, _ in fake.requested])
    assert len(fake.requested) >= 2 and gaps.min() >= 2.0 - 1e-9, fake.requested
    # PX4's AUTOPILOT_VERSION reached MAVROS: its next answer holds the firmware
    fake.info = vehicle_info((1, 16, 0))
    fake.run(2.5)
    ok, message, out = rt.start(fake.t)
    fake.handle(out)
    assert ok, message
    table = [t for _, lv, t in fake.events if t.startswith("preflight (MAVROS)")][-1]
    row = [r for r in table.splitlines() if r.startswith("firmware")][0]
    assert "1.16.0" in row and row.endswith(" GO"), row
    n_req, n_info = len(fake.requested), len([c for c in fake.calls if c.key == "vehicle_info"])
    fake.run(12.0, reference=([0.5, 0.0, 0.0], 0.0))
    assert len(fake.requested) == n_req
    assert len([c for c in fake.calls if c.key == "vehicle_info"]) == n_info
    assert fake.state() == "OFFBOARD_ACTIVE"


def test_preflight_go_asks_only_until_answered_and_judges_the_mavros_evidence():
    rt = runtime(command="velocity")
    fake = FakeMavros(rt)
    ok, message = preflight_start(fake)
    assert ok, message
    # every parameter asked once (answered at once), refreshed every 10 s
    assert sorted(fake.asked) == sorted(PX4_PARAMS)
    fake.run(10.0)
    assert sorted(fake.asked) == sorted(list(PX4_PARAMS) * 2)
    (table,) = [t for _, lv, t in fake.events if t.startswith("preflight (MAVROS)")]
    rows = {line.split()[0]: line for line in table.splitlines()[2:] if line.strip()}
    assert rows["firmware"].split()[1] == "1.16.0" and rows["firmware"].endswith("GO")
    assert "estimated (SERVO_OUTPUT_RAW)" in rows["rotor"]
    assert "5 (HOLD)" in rows["COM_OBL_RC_ACT"] and rows["COM_OBL_RC_ACT"].endswith("GO")
    # odometry is MAVROS's state source: the MAVLink preflight's fallback note (WARN)
    att = [x for x in table.splitlines() if x.startswith("telemetry attitude")]
    assert att and "ODOMETRY" in att[0] and att[0].endswith("WARN")
    # the vehicle's health from /mavros/battery, gpsstatus/gps1/raw, estimator_status and
    # home_position/home: the MAVLink rows and verdicts
    assert "80 % (16.20 V)" in rows["battery"] and rows["battery"].endswith(" GO")
    assert "fix type 3, 10 sats" in rows["GPS"] and rows["GPS"].endswith(" GO")
    assert "flags 0x33f (healthy)" in rows["EKF"] and rows["EKF"].endswith(" GO")
    home = [r for r in table.splitlines() if r.startswith("home position")][0]
    assert "47.397742, 8.545594, 488.0 m" in home and home.endswith(" GO")


def _health_rows(fake):
    table = [t for _, lv, t in fake.events if t.startswith("preflight (MAVROS)")][-1]
    return {r.split()[0]: r for r in table.splitlines() if r.strip()}


@pytest.mark.parametrize(
    "change, row, value, verdict",
    [
        # MAVROS divides PX4's integer % by 100 in float32: 0.29f * 100 = 28.99999...
        ({"battery": 0.29}, "battery", "29 % (16.20 V)", "GO"),
        ({"battery": 0.25}, "battery", "25 % (16.20 V)", "GO"),  # the reserve itself
        # global_position/raw/fix instead of GPSRAW: STATUS_FIX means fix_type > 2
        ({"gps": None, "fix": 0}, "GPS", "fix type 3 ", "GO"),
        # indoors: no GPS, but the EKF has a relative horizontal position (vision / flow)
        ({"gps": None, "ekf": EKF_OK[:4] + EKF_OK[5:6]}, "GPS", "no GPS_RAW_INT", "WARN"),
        ({"gps": 0, "ekf": EKF_OK[:4] + EKF_OK[5:6]}, "GPS", "fix type 0 (no 3D fix)", "WARN"),
    ],
)
def test_preflight_health_through_mavros_that_allows_the_start(change, row, value, verdict):
    rt = runtime(command="velocity")
    fake = FakeMavros(rt)
    for k, v in change.items():
        setattr(fake, k, v)
    ok, message = preflight_start(fake)
    assert ok, message
    r = _health_rows(fake)[row]
    assert value in r and r.endswith(f" {verdict}"), r
    assert fake.modes_requested()[0] == "OFFBOARD"  # the start went on


def test_px4_attitude_target_through_mavros_is_the_rate_setpoint_echo():
    """``/mavros/setpoint_raw/target_attitude`` (MAVROS turns PX4's FRD ATTITUDE_TARGET
    into FLU: x, -y, -z) comes out on ``rate_setpoint`` as PX4 holds it: thrust and FRD
    body rates (the same columns as over the MAVLink transport)."""
    from lpv_sysid.mavlink.bridge import RATE_INPUT_NAMES

    rt = runtime(command="rate_setpoint")
    rt.open(0.0)  # the shell opens the runtime: the echo tap
    fake = FakeMavros(rt)
    fake.run(0.5)
    # MAVROS's message for PX4's p=0.3, q=-0.2, r=0.1 (FRD), thrust 0.62: body_rate in FLU
    msg = F(
        "mavros_msgs/msg/AttitudeTarget",
        header=messages.header_msg(F, round(fake.t * 1e9)),
        type_mask=128,
        body_rate=F("geometry_msgs/msg/Vector3", x=0.3, y=0.2, z=-0.1),
        thrust=0.62,
    )
    fake.handle(rt.on_message("mavros_target_attitude", msg, fake.t))
    fake.run(0.01)
    (echo,) = fake.setpoints("rate_setpoint")
    assert list(echo.name) == list(RATE_INPUT_NAMES)
    np.testing.assert_allclose(np.asarray(echo.position), [0.62, 0.3, -0.2, 0.1], atol=1e-6)


@pytest.mark.parametrize(
    "u, rates_frd, thrust",
    [
        # the rate plant's input (thrust, p_sp, q_sp, r_sp) goes out unchanged ...
        ((0.5, 0.3, -0.4, 0.1), (0.3, -0.4, 0.1), 0.5),
        # ... clipped to PX4's ranges (RateSetpointTransport: thrust 0.05..0.95, |rate| <= 2)
        ((0.99, 2.5, 0.0, -3.0), (2.0, 0.0, -2.0), 0.95),
    ],
)
def test_rate_plant_command_through_mavros_attitude_target(u, rates_frd, thrust):
    rt = runtime(command="rate_setpoint")
    fake = started(FakeMavros(rt, mode="AUTO.LOITER", armed=True), actuator=u)
    fake.run(4.0, actuator=u)
    assert fake.state() == "OFFBOARD_ACTIVE"
    sp = fake.setpoints("mavros_attitude")[-1]
    assert sp.type_mask == 128
    # FLU on the topic: MAVROS turns (x, y, z) into FRD (x, -y, -z)
    flu = [sp.body_rate.x, sp.body_rate.y, sp.body_rate.z]
    np.testing.assert_allclose(flu, [rates_frd[0], -rates_frd[1], -rates_frd[2]], atol=1e-6)
    assert sp.thrust == pytest.approx(thrust, abs=1e-6)


# --------------------------------------------------- PX4 failsafe modes and stale evidence
def test_a_failsafe_during_offboard_ends_failed_and_commands_no_mode():
    """PX4 leaves OFFBOARD by a failsafe (Hold on offboard loss, MAV_STATE_CRITICAL in its
    HEARTBEAT): the bridge concludes "left OFFBOARD", FAILED, the failsafe keeps control
    (no mode commanded); the status names the failsafe and the mode PX4 shows."""
    rt = runtime(command="velocity")
    fake = started(FakeMavros(rt, armed=True))
    fake.run(3.0, reference=([0.5, 0.0, 0.0], 0.0))
    assert fake.state() == "OFFBOARD_ACTIVE"
    fake.mode, fake.system_status = "AUTO.LOITER", 5
    fake.run(2.0, reference=([0.5, 0.0, 0.0], 0.0))
    assert fake.state() == "FAILED" and fake.modes_requested() == ["OFFBOARD"]
    assert "vehicle left OFFBOARD" in rt.core.status(fake.t)["reason"]
    texts = [t for _, _, t in fake.events]
    assert any(
        "PX4 failsafe active, vehicle in AUTO.LOITER (MAV_STATE_CRITICAL)" in t for t in texts
    ), texts
    st = rt.mavros_link.status(fake.t)
    assert st["px4_failsafe"] == "AUTO.LOITER (MAV_STATE_CRITICAL)"
    assert st["mavros_mode"] == "AUTO.LOITER"
    # the failsafe ends (the pilot picks a mode): reported, nothing claimed
    fake.mode, fake.system_status = "POSCTL", 4
    fake.run(1.5)
    assert rt.mavros_link.status(fake.t)["px4_failsafe"] == "false"
    assert fake.state() == "FAILED" and fake.modes_requested() == ["OFFBOARD"]


@pytest.mark.parametrize("land_applied", [True, False])
def test_a_failsafe_hold_is_not_the_requested_hold(land_applied):
    """Hand-back chain HOLD, LAND while PX4's failsafe put the vehicle in Hold (the state
    shows AUTO.LOITER, system_status CRITICAL): HOLD is not confirmed by it; LAND, applied
    by PX4 outside the failsafe, is (DONE, "LAND after HOLD"); refused, the run ends FAILED
    -- never "vehicle in HOLD"."""
    rt = runtime(command="velocity")
    applies = {"OFFBOARD", "AUTO.LAND"} if land_applied else {"OFFBOARD"}
    fake = started(FakeMavros(rt, armed=True, applies=applies))
    fake.run(3.0, reference=([0.5, 0.0, 0.0], 0.0))
    assert fake.state() == "OFFBOARD_ACTIVE"
    fake.handle(rt.abort(fake.t)[2])
    fake.mode, fake.system_status = "AUTO.LOITER", 5  # PX4's failsafe, not the request

    def set_mode(out):  # a mode change PX4 applies ends its failsafe (OnModeChangeOrDisarm)
        before = fake.mode
        FakeMavros.handle(fake, out)
        if fake.mode != before:
            fake.system_status = 4

    fake.handle = set_mode
    fake.run(12.0)
    assert fake.modes_requested() == ["OFFBOARD", "AUTO.LOITER", "AUTO.LAND"]
    reason = rt.core.status(fake.t)["reason"]
    assert "vehicle in HOLD" not in reason
    if land_applied:
        assert fake.state() == "DONE" and "vehicle in LAND after HOLD" in reason, reason
    else:
        assert fake.state() == "FAILED" and "hand-back NOT confirmed" in reason, reason


@pytest.mark.parametrize(
    "silent, named",
    [
        ("battery", "battery: unknown"),
        ("ekf", "EKF: no ESTIMATOR_STATUS"),
        ("home", "home position: not set"),
        ("rc_out", "rotor speeds: none"),
    ],
)
def test_health_evidence_expires_when_mavros_stops_publishing_it(silent, named):
    """A health topic MAVROS stops publishing (while /mavros/state stays fresh) keeps its
    last value for ``mavros.health_max_age`` s only: GO within it, then the fact counts as
    missing (the verdict of one never received) and ``start`` is refused."""
    rt = runtime(command="velocity", **{"mavros.health_max_age": 5.0})
    fake = FakeMavros(rt)
    fake.run(2.0)
    setattr(fake, silent, None if silent != "rc_out" else False)
    fake.run(3.0)  # 3-4 s since the last message: still evidence
    ok, message, out = rt.start(fake.t)
    fake.handle(out)
    assert ok, message
    fake.handle(rt.abort(fake.t)[2])
    rt2 = runtime(command="velocity", **{"mavros.health_max_age": 5.0})
    fake2 = FakeMavros(rt2)
    fake2.run(2.0)
    setattr(fake2, silent, None if silent != "rc_out" else False)
    fake2.run(6.0)  # > 5 s: expired
    ok, message, out = rt2.start(fake2.t)
    fake2.handle(out)
    assert not ok and named in message, message
    assert fake2.mode_calls() == []
    assert any("older than 5 s ignored" in t for _, _, t in fake2.events), fake2.events


def test_evidence_fresh_copy_drops_only_the_stale_facts():
    from lpv_sysid.mavlink.preflight import MavrosEvidence

    ev = MavrosEvidence()
    ev.put("battery", (80.0, 16.2), 0.0)
    ev.put("home", (47.0, 8.0, 400.0), 9.0)
    ev.saw("ODOMETRY", 1.0)
    ev.saw("HIGHRES_IMU", 9.5)
    ev.estimator_flags = 0x33F  # set in code, no stamp: kept
    f = ev.fresh(10.0, 5.0)
    assert f.battery is None and f.home == (47.0, 8.0, 400.0) and f.estimator_flags == 0x33F
    assert f.seen == {"HIGHRES_IMU"} and ev.seen == {"ODOMETRY", "HIGHRES_IMU"}
    assert ev.battery == (80.0, 16.2)  # the original is untouched
    assert ev.stale(10.0, 5.0) == ["battery 10.0 s old", "ODOMETRY 9.0 s old"]
    with pytest.raises(ValueError, match="not an expiring"):
        ev.put("mode", None, 0.0)


@pytest.mark.parametrize("preflight", [True, False])
def test_vehicle_record_through_mavros(preflight):
    """transport mavros: the vehicle record from MAVROS -- firmware and HIL flag from
    vehicle_info_get, the parameter snapshot by param/pull, list_parameters and
    get_parameters (the param node's own parameters left out), battery, and the home's
    latitude/longitude (MAVROS' geo altitude is the ellipsoid height: not AMSL); no PX4
    boot time (px4_clock empty, with the note why); published once complete, not at the
    poll rate, and the same mapping as the MAVLink record."""
    from lpv_sysid.mavlink.telemetry import VehicleRecord

    rt = runtime(command="velocity", **{"mavros.preflight": preflight})
    fake = FakeMavros(rt)
    fake.params = {f"P{k:03d}_X": float(k) for k in range(450)} | {
        "SYS_AUTOSTART": 10040,
        "SYS_HITL": 2,
        "MAV_TYPE": 2,
        **PX4_PARAMS,
    }
    fake.info = VehicleInfo(  # as MAVROS 2.10 answered for PX4 v1.16 SITL (measured)
        available_info=1,  # HEARTBEAT only: no AUTOPILOT_VERSION yet, asked again
        sysid=1,
        compid=1,
        base_mode=29,
        flight_sw_version=px4.encode_flight_sw_version(1, 16, 0),
        flight_custom_version="6ea3539157000000",
        board_version=1,
        uid=5283920058631409236,
    )
    fake.run(3.0)
    assert fake.rt.vehicle.version is None  # the zeros of a VehicleInfo without it
    fake.info.available_info = 3
    fake.run(3.0)
    records = fake.setpoints("vehicle_record")
    assert 1 <= len(records) <= 6, len(records)  # not at the 250 Hz poll rate
    kind, v = messages.vehicle_record_from_msg(records[-1])
    assert kind == "utc" and set(v) == set(VehicleRecord().summary())
    assert v["px4_parameters"] == pytest.approx(fake.params)  # 464 in 3 batches
    assert fake.pulls == 1
    assert v["kind"] == "SIH" and v["hil_flag"] is False
    assert v["airframe"] == {"SYS_AUTOSTART": 10040, "MAV_TYPE": 2, "CA_AIRFRAME": None}
    assert v["firmware"]["flight_sw_version"] == "v1.16.0"
    assert v["firmware"]["flight_custom_version"] == "6ea3539157000000"
    assert v["firmware"]["uid"] == 5283920058631409236
    assert v["battery"]["start"]["voltage_v"] == pytest.approx(16.2)
    assert v["battery"]["start"]["remaining_pct"] == 80
    site = v["site"]
    assert (site["latitude_deg"], site["longitude_deg"]) == (47.397742, 8.545594)
    assert site["altitude_amsl_m"] is None and site["altitude_wgs84_m"] == 488.0
    clk = v["px4_clock"]
    assert clk["boot_ns"] is None and clk["boot_samples"] == 0 and "MAVROS" in clk["note"]
    # a parameter set after the snapshot: the preflight's 10 s refresh carries it over
    fake.params["COM_OBL_RC_ACT"] = 1
    fake.run(12.0)
    _, v = messages.vehicle_record_from_msg(fake.setpoints("vehicle_record")[-1])
    assert v["px4_parameters"]["COM_OBL_RC_ACT"] == (1 if preflight else 5)
    # the battery at the end: refreshed every 10 s (1 Hz readings here)
    assert v["battery"]["end"]["stamp_ns"] >= round((fake.t - 11.0) * 1e9)
