"""io/messages/: build -> parse round trips (rosbags and the rclpy stand-in), CDR
round trips through the Jazzy typestore, frame conventions and bad-input errors."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.io import messages
from lpv_sysid.models.quadrotor import INPUT_NAMES

RNG = np.random.default_rng(3)
STAMP = 1_700_000_123_456_789_012


@pytest.fixture(scope="module")
def rb():
    return messages.MsgFactory.rosbags()


@pytest.fixture(scope="module", params=["rosbags", "rclpy"])
def fac(request, rb):
    return rb if request.param == "rosbags" else messages.MsgFactory.rclpy()


def cdr_round_trip(rb, msg, typename):
    ts = rb.typestore
    return ts.deserialize_cdr(ts.serialize_cdr(msg, typename), typename)


def random_state():
    return (
        RNG.normal(size=3) * 10,
        np.array([0.3, -0.2, 2.0]) * RNG.uniform(-1, 1, 3),
        RNG.normal(size=3) * 3,
        RNG.normal(size=3),
    )


# ------------------------------------------------------------------- stamps
@pytest.mark.parametrize(
    "ns", [0, 1, 999_999_999, 1_000_000_000, STAMP % 2**62 // 1000, -1, -1_500_000_000]
)
def test_stamp_round_trip(rb, ns):
    t = messages.time_msg(rb, ns)
    assert 0 <= t.nanosec < 1_000_000_000
    assert messages.stamp_ns_from_time(t) == ns


def test_stamp_known_split_and_overflow(rb):
    t = messages.time_msg(rb, 12_345_000_000_007)
    assert (t.sec, t.nanosec) == (12345, 7)
    with pytest.raises(messages.MessageError, match="int32"):
        messages.time_msg(rb, 2**31 * 1_000_000_000)
    bad = rb("builtin_interfaces/msg/Time", sec=1, nanosec=1_000_000_000)
    with pytest.raises(messages.MessageError, match="nanosec"):
        messages.stamp_ns_from_time(bad)


def test_message_error_is_config_and_value_error():
    assert issubclass(messages.MessageError, ConfigError)
    assert issubclass(messages.MessageError, ValueError)
    assert issubclass(messages.MessageError, LpvSysidError)


# -------------------------------------------------------------------- state
def test_state_round_trip(fac):
    for _ in range(5):
        pos, eul, v, w = random_state()
        msg = messages.odometry_from_state(fac, STAMP, pos, eul, v, w)
        s = messages.state_from_odometry(msg)
        assert s.stamp_ns == STAMP
        assert s.t == pytest.approx(STAMP * 1e-9, rel=1e-15)
        for a, b in ((s.pos_ned, pos), (s.euler, eul), (s.v_body, v), (s.omega, w)):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_state_wire_content_is_enu_flu(rb):
    # flying north at 2 m/s level, heading north, climbing 1 m/s, yawing right 0.1 rad/s
    msg = messages.odometry_from_state(
        rb, 5, [10.0, 20.0, -30.0], [0.0, 0.0, 0.0], [2.0, 0.0, -1.0], [0.0, 0.0, 0.1]
    )
    assert msg.header.frame_id == "odom" and msg.child_frame_id == "base_link"
    p = msg.pose.pose.position
    assert (p.x, p.y, p.z) == (20.0, 10.0, 30.0)  # east, north, up
    o = msg.pose.pose.orientation
    yaw = Rotation.from_quat([o.x, o.y, o.z, o.w]).as_euler("ZYX")[0]
    assert yaw == pytest.approx(np.pi / 2, abs=1e-14)  # facing north = ENU yaw 90 deg
    lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
    assert (lin.x, lin.y, lin.z) == (2.0, -0.0, 1.0)
    assert ang.z == -0.1


def test_state_cdr_round_trip(rb):
    pos, eul, v, w = random_state()
    msg = messages.odometry_from_state(rb, STAMP, pos, eul, v, w, pose_covariance=np.eye(6) * 0.01)
    back = cdr_round_trip(rb, msg, "nav_msgs/msg/Odometry")
    s = messages.state_from_odometry(back)
    np.testing.assert_allclose(s.euler, eul, atol=1e-12)
    np.testing.assert_array_equal(back.pose.covariance, (np.eye(6) * 0.01).ravel())


def test_state_wrong_frame_and_nan(rb):
    msg = messages.odometry_from_state(
        rb, 1, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), frame_id="map"
    )
    with pytest.raises(
        messages.MessageError, match=r"state.header: expected frame_id 'odom', got 'map'"
    ):
        messages.state_from_odometry(msg)
    assert messages.state_from_odometry(msg, frame_id=None).stamp_ns == 1
    msg = messages.odometry_from_state(rb, 1, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    msg.twist.twist.linear.y = float("nan")
    with pytest.raises(
        messages.MessageError,
        match=r"state.twist.twist.linear: non-finite value\(s\) at index \[1\]",
    ):
        messages.state_from_odometry(msg)
    msg = messages.odometry_from_state(rb, 1, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    msg.pose.pose.orientation.w = 0.0
    with pytest.raises(messages.MessageError, match="unit quaternion"):
        messages.state_from_odometry(msg)
    with pytest.raises(messages.MessageError, match=r"state.euler: non-finite"):
        messages.odometry_from_state(rb, 1, np.zeros(3), [0, np.inf, 0], np.zeros(3), np.zeros(3))
    with pytest.raises(messages.MessageError, match=r"state.v_body: expected 3 values, got 2"):
        messages.odometry_from_state(rb, 1, np.zeros(3), np.zeros(3), np.zeros(2), np.zeros(3))


# ------------------------------------------------------------------ joint states
def test_channel_round_trips(fac):
    om = RNG.uniform(300, 900, 4)
    t, back = messages.rotor_speeds_from_joint_state(messages.rotor_speeds_msg(fac, STAMP, om))
    np.testing.assert_array_equal(back, om)
    assert t == pytest.approx(STAMP * 1e-9, rel=1e-15)
    ue = RNG.uniform(-1, 1, 4)
    msg = messages.excitation_msg(fac, STAMP, ue)
    assert list(msg.name) == ["ue_t", "ue_a", "ue_e", "ue_r"]
    np.testing.assert_array_equal(messages.excitation_from_joint_state(msg)[1], ue)
    u = RNG.normal(size=4)
    msg = messages.actuator_command_msg(fac, STAMP, u)
    assert list(msg.name) == ["ut", "ua", "ue", "ur"]
    assert len(msg.velocity) == 0 and len(msg.effort) == 0
    np.testing.assert_array_equal(messages.actuator_command_from_joint_state(msg)[1], u)


def test_channels_by_name_reordered_and_cdr(rb):
    msg = messages.joint_state(rb, 7, ["b", "a", "c"], position=[2.0, 1.0, 3.0])
    back = cdr_round_trip(rb, msg, "sensor_msgs/msg/JointState")
    t, v = messages.channels_from_joint_state(back, ["a", "b", "c"])
    np.testing.assert_array_equal(v, [1.0, 2.0, 3.0])
    assert t == 7e-9


def test_joint_state_errors(rb):
    msg = messages.joint_state(rb, 1, ["ue_t", "ue_a", "ue_e"], position=[0.0, 0.1, 0.2])
    with pytest.raises(messages.MessageError, match=r"missing channel\(s\) \['ue_r'\]"):
        messages.excitation_from_joint_state(msg)
    msg = messages.excitation_msg(rb, 1, [0.0, 0.1, 0.2, 0.3])
    msg.position[2] = np.nan
    with pytest.raises(
        messages.MessageError, match=r"non-finite value for channel\(s\) \['ue_e'\]"
    ):
        messages.excitation_from_joint_state(msg)
    msg = messages.rotor_speeds_msg(rb, 1, [1.0, 2, 3, 4])
    with pytest.raises(messages.MessageError, match=r"joint_state.position: 0 values for 4 names"):
        messages.channels_from_joint_state(msg, messages.ROTOR_NAMES, field="position")
    with pytest.raises(messages.MessageError, match="duplicate"):
        messages.joint_state(rb, 1, ["a", "a"], position=[1.0, 2.0])
    with pytest.raises(
        messages.MessageError, match=r"joint_state.velocity: expected 4 values, got 3"
    ):
        messages.rotor_speeds_msg(rb, 1, [1.0, 2.0, 3.0])


# -------------------------------------------------------------------------- imu
def test_imu_round_trip(fac):
    f_b, w, e = RNG.normal(size=3), RNG.normal(size=3), np.array([0.1, -0.2, 2.5])
    s = messages.imu_from_msg(messages.imu_msg(fac, STAMP, f_b, w, e))
    np.testing.assert_allclose(s.specific_force, f_b, atol=1e-12)
    np.testing.assert_allclose(s.omega, w, atol=1e-12)
    np.testing.assert_allclose(s.euler, e, atol=1e-12)
    s = messages.imu_from_msg(messages.imu_msg(fac, STAMP, f_b, w))
    assert s.euler is None


def test_imu_hover_specific_force_points_up_in_flu(rb):
    # hovering: accelerometer reads -g along FRD z (specific force up) -> +g along FLU z
    msg = messages.imu_msg(rb, 1, [0.0, 0.0, -9.80665], [0.0, 0.0, 0.0])
    assert msg.linear_acceleration.z == 9.80665
    assert msg.orientation_covariance[0] == -1.0
    back = cdr_round_trip(rb, msg, "sensor_msgs/msg/Imu")
    np.testing.assert_array_equal(messages.imu_from_msg(back).specific_force, [0.0, 0.0, -9.80665])


def test_imu_nan(rb):
    msg = messages.imu_msg(rb, 1, np.zeros(3), np.zeros(3))
    msg.angular_velocity.x = float("inf")
    with pytest.raises(messages.MessageError, match="imu.angular_velocity"):
        messages.imu_from_msg(msg)


# ------------------------------------------------------------ velocity reference
def test_reference_round_trip(fac):
    v, r = RNG.normal(size=3), 0.37
    t, v2, r2 = messages.reference_from_twist(messages.twist_reference_msg(fac, STAMP, v, r))
    np.testing.assert_allclose(v2, v, atol=1e-12)
    assert r2 == pytest.approx(r, abs=1e-12)


def test_reference_wire_content(rb):
    msg = messages.twist_reference_msg(rb, 3, [4.0, 1.0, -0.5], 0.2)
    lin, ang = msg.twist.linear, msg.twist.angular
    assert (lin.x, lin.y, lin.z) == (4.0, -1.0, 0.5)  # right -> -left, down -> -up
    assert (ang.x, ang.y, ang.z) == (0.0, -0.0, -0.2)
    assert msg.header.frame_id == "base_link"
    back = cdr_round_trip(rb, msg, "geometry_msgs/msg/TwistStamped")
    assert messages.reference_from_twist(back)[2] == 0.2
    msg.header.frame_id = "odom"
    with pytest.raises(
        messages.MessageError, match="velocity_reference.header: expected frame_id 'base_link'"
    ):
        messages.reference_from_twist(msg)


# ----------------------------------------------------------------------- status
def test_status_round_trip(fac):
    st = [
        messages.diagnostic_status(
            fac,
            "WARN",
            "controller",
            "clamped",
            {"phase": "lpv", "margin": 0.1 + 0.2, "n": 3, "ok": True},
        ),
        messages.diagnostic_status(fac, 0, "bridge", "link ok"),
    ]
    t, back = messages.status_from_diagnostic_array(messages.diagnostic_array(fac, STAMP, st))
    assert [(s.level, s.name, s.message) for s in back] == [
        (1, "controller", "clamped"),
        (0, "bridge", "link ok"),
    ]
    assert back[0].values == {
        "phase": "lpv",
        "margin": "0.30000000000000004",
        "n": "3",
        "ok": "true",
    }
    assert float(back[0].values["margin"]) == 0.1 + 0.2


def test_status_levels_and_cdr(rb):
    s = messages.diagnostic_status(rb, "error", "safety", "bound violated", {"v": 1.5})
    assert s.level == rb.get("diagnostic_msgs/msg/DiagnosticStatus").ERROR
    arr = messages.diagnostic_array(rb, 9, [s])
    back = cdr_round_trip(rb, arr, "diagnostic_msgs/msg/DiagnosticArray")
    _, out = messages.status_from_diagnostic_array(back)
    assert out[0].level == 2 and out[0].values == {"v": "1.5"}
    with pytest.raises(messages.MessageError, match="unknown level 'FATAL'"):
        messages.diagnostic_status(rb, "FATAL", "x")
    with pytest.raises(messages.MessageError, match="status.level: 7"):
        messages.diagnostic_status(rb, 7, "x")


def test_rclpy_factory_level_is_bytes():
    f = messages.MsgFactory.rclpy()
    s = messages.diagnostic_status(f, 2, "x")
    assert s.level == b"\x02"


def test_unknown_type(rb):
    with pytest.raises(messages.MessageError, match="unknown message type 'foo_msgs/msg/Bar'"):
        rb("foo_msgs/msg/Bar")


def test_topic_type_table():
    assert messages.TYPES["state"] == "nav_msgs/msg/Odometry"
    assert messages.TYPES["actuator_command"] == "sensor_msgs/msg/JointState"


# ------------------------------------------------------------- batch converters
def test_states_from_odometry_matches_single(fac):
    states = [random_state() for _ in range(20)]
    msgs = [messages.odometry_from_state(fac, STAMP + i, *s) for i, s in enumerate(states)]
    arr = messages.states_from_odometry(msgs)
    assert arr.stamp_ns.tolist() == [STAMP + i for i in range(20)]
    for k, s in enumerate(states):
        one = messages.state_from_odometry(msgs[k])
        assert arr.t[k] == one.t
        for name, val in zip(("pos_ned", "euler", "v_body", "omega"), s):
            np.testing.assert_allclose(
                getattr(arr, name)[k], getattr(one, name), rtol=0, atol=1e-15
            )
            np.testing.assert_allclose(getattr(arr, name)[k], val, atol=1e-12)


def test_states_from_odometry_errors_name_index(rb):
    msgs = [messages.odometry_from_state(rb, i, *np.zeros((4, 3))) for i in range(5)]
    msgs[3].twist.twist.angular.z = float("nan")
    with pytest.raises(messages.MessageError, match=r"state\[3\].twist.twist.angular: non-finite"):
        messages.states_from_odometry(msgs)
    msgs[3].twist.twist.angular.z = 0.0
    msgs[2].child_frame_id = "imu_link"
    with pytest.raises(
        messages.MessageError,
        match=r"state\[2\].child_frame_id: expected frame_id 'base_link', got 'imu_link'",
    ):
        messages.states_from_odometry(msgs)
    assert messages.states_from_odometry(msgs, child_frame_id=None).euler.shape == (5, 3)
    assert messages.states_from_odometry([]).pos_ned.shape == (0, 3)


def test_channels_from_joint_states(rb):
    vals = RNG.normal(size=(6, 4))
    msgs = [messages.actuator_command_msg(rb, i, v) for i, v in enumerate(vals)]
    t, out = messages.channels_from_joint_states(msgs, INPUT_NAMES)
    np.testing.assert_array_equal(out, vals)
    np.testing.assert_array_equal(t, np.arange(6) / 1e9)
    msgs[4] = messages.joint_state(rb, 4, ["ut", "ua", "ue"], position=[0.0, 0.0, 0.0])
    with pytest.raises(
        messages.MessageError, match=r"message 4: joint_state.name: missing channel\(s\) \['ur'\]"
    ):
        messages.channels_from_joint_states(msgs, INPUT_NAMES)
