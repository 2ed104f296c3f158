"""MAVROS mode of the bridge: the pure core (lpv_sysid/mavlink/bridge/mavros.py) against scipy's
Rotation as an independent oracle, and the node shell (transport: mavros) through the
rclpy stand-in with a fake MAVROS node publishing odom/imu and listening on cmd_vel."""

from __future__ import annotations

import os

import numpy as np
import pytest
import rclpy
import rclpy._standin as standin
from rclpy._standin import call_trigger as call
from rclpy._standin import spin_nodes as spin
from scipy.spatial.transform import Rotation

from lpv_sysid.errors import ConfigError
from lpv_sysid.io import messages
from lpv_sysid.mavlink.bridge import (
    MODE_CONTROL,
    MavrosConfig,
    MavrosCore,
    MavrosState,
    body_reference_to_local_enu,
    cmd_vel_msg,
    vehicle_mode_from_statuses,
)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "config")
NS = "lpv_sysid"
RNG = np.random.default_rng(11)
T_NED_ENU = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])
T_FRD_FLU = np.diag([1.0, -1, -1])


def oracle(euler, v_frd, r_frd):
    """Independent: scipy R_IB = Rz(psi) Ry(theta) Rx(phi) (seed 0 Eq. 1), the static
    NED->ENU permutation written out, and psi_dot = cos(phi) r / cos(theta) (Eq. 2, p=q=0)."""
    phi, theta, psi = euler
    R_IB = Rotation.from_euler("ZYX", [psi, theta, phi])
    v_ned = R_IB.apply(v_frd)
    return np.array([v_ned[1], v_ned[0], -v_ned[2]]), -np.cos(phi) * r_frd / np.cos(theta)


def enu_flu_quat_xyzw(euler):
    """ROS orientation of the NED/FRD attitude, composed with scipy (MAVROS's convention:
    q_enu_flu = q_ned_to_enu * q_ned_frd * q_frd_to_flu)."""
    phi, theta, psi = euler
    R = T_NED_ENU @ Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix() @ T_FRD_FLU
    return Rotation.from_matrix(R).as_quat()


def state(t, euler, stamp_ns=None):
    return messages.StateSample(
        t=t,
        pos_ned=np.zeros(3),
        euler=np.asarray(euler, float),
        v_body=np.zeros(3),
        omega=np.zeros(3),
        stamp_ns=int(t * 1e9) if stamp_ns is None else stamp_ns,
    )


# --------------------------------------------------------------------------- core math
def test_body_reference_to_local_enu_against_scipy():
    for _ in range(30):
        e = RNG.uniform([-0.8, -0.8, -np.pi], [0.8, 0.8, np.pi])
        v, r = RNG.normal(0, 2, 3), RNG.normal(0, 0.5)
        v_enu, yr = body_reference_to_local_enu(v, r, e)
        v_ref, yr_ref = oracle(e, v, r)
        np.testing.assert_allclose(v_enu, v_ref, atol=1e-12)
        assert yr == pytest.approx(yr_ref, abs=1e-12)
        # the same vector through the ROS route: R_ENU_FLU (scipy) applied to v FLU
        v_flu = v * np.array([1, -1, -1])
        np.testing.assert_allclose(
            v_enu, Rotation.from_quat(enu_flu_quat_xyzw(e)).apply(v_flu), atol=1e-12
        )
    # known values: level, facing north -> forward is ENU +y; facing east -> ENU +x
    np.testing.assert_allclose(
        body_reference_to_local_enu([1, 0, 0], 0, [0, 0, 0])[0], [0, 1, 0], atol=1e-15
    )
    np.testing.assert_allclose(
        body_reference_to_local_enu([1, 0, -1], 0.2, [0, 0, np.pi / 2])[0], [1, 0, 1], atol=1e-15
    )
    assert body_reference_to_local_enu([0, 0, 0], 0.2, [0, 0, 1.0])[1] == pytest.approx(-0.2)


def test_odometry_message_to_enu_setpoint_round_trip():
    """MAVROS odom (map/base_link, ENU/FLU, built with scipy) -> io/messages -> core ->
    cmd_vel message -> CDR -> fields equal the oracle."""
    f = messages.MsgFactory.rosbags()
    e = np.array([0.15, -0.25, 2.1])
    x, y, z, w = enu_flu_quat_xyzw(e)
    odom = f(
        "nav_msgs/msg/Odometry",
        header=messages.header_msg(f, 1_000_000_000, "map"),
        child_frame_id="base_link",
        pose=f(
            "geometry_msgs/msg/PoseWithCovariance",
            pose=f(
                "geometry_msgs/msg/Pose",
                position=f("geometry_msgs/msg/Point", x=1.0, y=2.0, z=3.0),
                orientation=f("geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w),
            ),
            covariance=np.zeros(36),
        ),
        twist=f(
            "geometry_msgs/msg/TwistWithCovariance",
            twist=f(
                "geometry_msgs/msg/Twist",
                linear=f("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0),
                angular=f("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0),
            ),
            covariance=np.zeros(36),
        ),
    )
    core = MavrosCore(MavrosConfig())
    s = core.on_odometry(1.0, messages.state_from_odometry(odom, frame_id="map"))
    np.testing.assert_allclose(s.pos_ned, [2.0, 1.0, -3.0])
    core.start(1.0)
    v_frd, r = np.array([1.0, -0.5, 0.2]), 0.3
    out = core.on_velocity_reference(1.01, v_frd, r, stamp=1.01)
    (sp,) = out.setpoints
    msg = cmd_vel_msg(f, 1_010_000_000, sp, "map")
    back = f.typestore.deserialize_cdr(
        f.typestore.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__
    )
    v_ref, yr_ref = oracle(e, v_frd, r)
    lin, ang = back.twist.linear, back.twist.angular
    np.testing.assert_allclose([lin.x, lin.y, lin.z], v_ref, atol=1e-9)
    np.testing.assert_allclose([ang.x, ang.y, ang.z], [0, 0, yr_ref], atol=1e-9)
    assert back.header.frame_id == "map" and back.header.stamp.sec == 1


# ----------------------------------------------------------------------- core safety
def run(core, t0, t1, dt, ref=None, odom=True):
    """Step the core on a simulated clock; feed odometry (and a reference) every dt."""
    sent, events = [], []
    for t in np.arange(t0, t1, dt):
        if odom:
            core.on_odometry(t, state(t, [0.0, 0.0, 0.0]))
        if ref is not None:
            o = core.on_velocity_reference(t, *ref, stamp=t)
            sent += o.setpoints
            events += o.events
        o = core.step(t)
        sent += o.setpoints
        events += o.events
    return sent, events


def test_prestream_stream_then_stale_input_stops_stream():
    core = MavrosCore(
        MavrosConfig(setpoint_rate_hz=20.0, input_timeout=0.2, send_on_command=False)
    )
    ev = core.start(0.0)
    assert core.state == MavrosState.PRESTREAM and "operator" in ev[0].reason
    sent, _ = run(core, 0.0, 1.0, 0.025)  # no reference yet: zero velocity, 20 Hz
    assert len(sent) == 20 and all(np.all(s.v_enu == 0) for s in sent)
    sent, ev = run(core, 1.0, 2.0, 0.025, ref=([2.0, 0.0, 0.0], 0.0))
    assert (
        core.state == MavrosState.STREAMING and ev[0].reason == "first velocity reference received"
    )
    assert len(sent) == 20
    np.testing.assert_allclose(sent[-1].v_enu, [0.0, 2.0, 0.0], atol=1e-12)  # north
    sent, ev = run(core, 2.0, 3.0, 0.025)  # references stop at t = 1.975
    assert core.state == MavrosState.FAILED
    assert all(s.t <= 1.975 + 0.2 + 1e-9 for s in sent)  # nothing after input_timeout
    assert "stale input" in ev[0].reason and "COM_OBL_RC_ACT" in ev[0].reason
    assert ev[0].level == "warn"
    st = core.status(3.0)
    assert st["state"] == "FAILED" and st["streaming"] == "False"
    assert st["mode_control"] == MODE_CONTROL and "mavros_msgs" in st["armed"]
    # nothing more is streamed until an explicit start (auto_start only acts from IDLE)
    assert run(core, 3.0, 3.5, 0.025, ref=([1.0, 0, 0], 0.0))[0] == []


def test_stale_attitude_abort_and_auto_start():
    core = MavrosCore(MavrosConfig(telemetry_max_age=0.1, auto_start=True))
    out = core.on_velocity_reference(0.0, [1.0, 0.0, 0.0], 0.0)
    assert core.state == MavrosState.STREAMING and out.setpoints == []  # no attitude yet
    out = core.step(0.001)
    assert core.state == MavrosState.FAILED and out.events[0].level == "error"
    assert "cannot be rotated" in out.events[0].reason
    core.start(1.0)
    sent, _ = run(core, 1.0, 1.5, 0.01, ref=([0.0, 1.0, 0.0], 0.0))
    np.testing.assert_allclose(sent[-1].v_enu, [1.0, 0.0, 0.0], atol=1e-12)  # right = east
    ev = core.abort(1.5, "abort service")
    assert core.state == MavrosState.DONE and ev[0].level == "info"
    assert core.step(1.6).setpoints == []
    assert core.shutdown(1.7) == []  # already stopped: nothing to do


def test_prestream_timeout_and_pilot_leaving_offboard():
    core = MavrosCore(MavrosConfig(prestream_timeout=2.0))
    core.start(0.0)
    st = [messages.StatusSample(0, "mavros: Heartbeat", "Normal", {"Mode": "POSCTL"})]
    assert vehicle_mode_from_statuses(st) == "POSCTL"
    core.on_diagnostics(0.5, st)  # not yet in OFFBOARD: keep streaming
    assert core.step(1.0).setpoints and core.state == MavrosState.PRESTREAM
    out = core.step(2.5)
    assert core.state == MavrosState.FAILED and "prestream_timeout" in out.events[0].reason
    core.start(3.0)
    core.on_diagnostics(
        3.1, [messages.StatusSample(0, "mavros: Heartbeat", "", {"Mode": "OFFBOARD"})]
    )
    core.on_diagnostics(
        3.2, [messages.StatusSample(0, "mavros: Heartbeat", "", {"Mode": "AUTO.LOITER"})]
    )
    out = core.step(3.3)
    assert core.state == MavrosState.FAILED and out.setpoints == []
    assert "left OFFBOARD (now AUTO.LOITER)" in out.events[0].reason
    assert core.status(3.3)["vehicle_mode"] == "AUTO.LOITER"


def test_bad_inputs_are_rejected_and_reported():
    core = MavrosCore(MavrosConfig())
    core.on_odometry(0.0, state(0.0, [0, 0, 0]))
    assert core.on_odometry(0.01, state(0.01, [0, 0, 0], stamp_ns=0)) is None  # not newer
    core.start(0.0)
    out = core.on_velocity_reference(0.01, [np.nan, 0, 0], 0.0)
    assert out.setpoints == [] and "3 finite values" in out.events[0].reason
    core.on_velocity_reference(0.02, [1, 0, 0], 0.0, stamp=5.0)
    out = core.on_velocity_reference(0.03, [1, 0, 0], 0.0, stamp=4.0)
    assert out.setpoints == [] and "out-of-order" in out.events[0].reason
    st = core.status(0.03)
    assert st["rejected_inputs"] == "2" and st["out_of_order"] == "1"


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"command": "attitude_rate", "interfaces": "common"}, "mavros_msgs"),
        ({"setpoint_rate_hz": 2.0}, "setpoint_rate_hz"),
        ({"namespace": "mavros"}, "namespace"),
        ({"auto_start": "yes"}, "auto_start"),
        ({"frame": "x"}, r"mavros: unknown key\(s\) \['frame'\]"),
    ],
)
def test_config_validation(bad, match):
    with pytest.raises(ConfigError, match=match):
        MavrosConfig.from_dict(bad)


# ------------------------------------------------------------------------ node shell
@pytest.fixture
def fresh():
    standin.reset()
    yield
    rclpy.try_shutdown()


def ros_args(*pairs):
    args = [
        "node",
        "--ros-args",
        "--params-file",
        os.path.join(CONFIG, "mavlink_bridge_node.yaml"),
    ]
    for k, v in pairs:
        args += ["-p", f"{k}:={v}"]
    return args


def test_node_mavros_parameters_topics_qos(fresh):
    from rclpy.qos import QoSReliabilityPolicy

    from lpv_sysid.nodes.mavlink_bridge_node import MavlinkBridgeNode

    rclpy.init(args=ros_args(("transport", "mavros"), ("mavros.interfaces", "common")))
    node = MavlinkBridgeNode(namespace=NS)
    try:
        assert node.get_parameter("transport").value == "mavros"
        assert node.get_parameter("mavros.odom_frame_id").value == "map"
        assert node.core.config.setpoint_rate_hz == 50.0 and node.core.config.input_timeout == 0.5
        assert dict(node.get_topic_names_and_types()) == {
            "/lpv_sysid/state": ["nav_msgs/msg/Odometry"],
            "/lpv_sysid/imu": ["sensor_msgs/msg/Imu"],
            "/lpv_sysid/status": ["diagnostic_msgs/msg/DiagnosticArray"],
            "/lpv_sysid/velocity_reference": ["geometry_msgs/msg/TwistStamped"],
            "/mavros/setpoint_velocity/cmd_vel": ["geometry_msgs/msg/TwistStamped"],
            "/mavros/local_position/odom": ["nav_msgs/msg/Odometry"],
            "/mavros/imu/data": ["sensor_msgs/msg/Imu"],
            "/diagnostics": ["diagnostic_msgs/msg/DiagnosticArray"],
        }
        best, rel = QoSReliabilityPolicy.BEST_EFFORT, QoSReliabilityPolicy.RELIABLE
        for topic in ("/mavros/local_position/odom", "/mavros/imu/data"):
            assert standin.find_subscription(node, topic).qos_profile.reliability == best
        assert (
            standin.find_publisher(
                node, "/mavros/setpoint_velocity/cmd_vel"
            ).qos_profile.reliability
            == rel
        )
        assert standin.find_subscription(node, "velocity_reference").qos_profile.reliability == rel
    finally:
        node.destroy_node()
    rclpy.try_shutdown()
    standin.reset()
    rclpy.init(args=ros_args(("transport", "dds")))
    with pytest.raises(ConfigError, match="transport must be"):
        MavlinkBridgeNode(namespace=NS)


def test_node_mavros_reference_to_enu_setpoint_and_stale_stop(fresh):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu

    from lpv_sysid.nodes.mavlink_bridge_node import MavlinkBridgeNode

    rclpy.init(args=ros_args(("transport", "mavros"), ("mavros.interfaces", "common")))
    node = MavlinkBridgeNode(namespace=NS)
    mavros = rclpy.create_node("mavros")  # fake MAVROS + excitation source
    f = messages.MsgFactory.rclpy()
    e = np.array([-0.1, 0.2, 0.7])  # NED/FRD attitude of the vehicle
    ros_q = enu_flu_quat_xyzw(e)
    pub_odom = mavros.create_publisher(
        Odometry, "/mavros/local_position/odom", qos_profile_sensor_data
    )
    pub_imu = mavros.create_publisher(Imu, "/mavros/imu/data", qos_profile_sensor_data)
    now_ns = lambda: mavros.get_clock().now().nanoseconds  # noqa: E731

    def odom_tick():
        m = messages.odometry_from_state(
            f, now_ns(), [1.0, 2.0, -3.0], e, [0.5, 0, 0], [0, 0, 0.1], frame_id="map"
        )
        pub_odom.publish(m)
        pub_imu.publish(messages.imu_msg(f, now_ns(), [0.0, 0.0, -9.81], [0.0, 0.0, 0.1], e))

    mavros.create_timer(0.02, odom_tick)
    cmd = []
    mavros.create_subscription(TwistStamped, "/mavros/setpoint_velocity/cmd_vel", cmd.append, 10)
    states, status = [], []
    mavros.create_subscription(
        Odometry, "/lpv_sysid/state", states.append, qos_profile_sensor_data
    )
    mavros.create_subscription(DiagnosticArray, "/lpv_sysid/status", status.append, 100)
    pub_ref = mavros.create_publisher(TwistStamped, "/lpv_sysid/velocity_reference", 10)
    v_frd, r = np.array([1.0, 0.5, -0.2]), 0.1
    ref_timer = mavros.create_timer(
        0.02, lambda: pub_ref.publish(messages.twist_reference_msg(f, now_ns(), v_frd, r))
    )
    try:
        spin([node, mavros], 0.5)
        assert cmd == []  # nothing before start
        assert call(mavros, [node], "/lpv_sysid/mavlink_bridge/start").success
        spin([node, mavros], 1.0)
        assert node.core.state == MavrosState.STREAMING
        v_ref, yr_ref = oracle(e, v_frd, r)
        last = cmd[-1].twist
        np.testing.assert_allclose([last.linear.x, last.linear.y, last.linear.z], v_ref, atol=1e-9)
        assert (
            last.angular.z == pytest.approx(yr_ref, abs=1e-12) and cmd[-1].header.frame_id == "map"
        )
        assert len(cmd) >= 50  # 50 Hz rate + on-command forwarding
        # odom republished on state in the project's frames (odom / base_link), same attitude
        q = states[-1].pose.pose.orientation
        assert abs(abs(np.dot([q.x, q.y, q.z, q.w], ros_q)) - 1) < 1e-9
        assert states[-1].header.frame_id == "odom"
        # references stop: the stream stops within input_timeout (0.5 s, config) + one tick
        mavros.destroy_timer(ref_timer)
        t_stop = now_ns()
        spin([node, mavros], 1.0)
    finally:
        node.destroy_node()
    timeout_ns = node.core.config.input_timeout * 1e9
    late = [m for m in cmd if messages.stamp_ns_of(m) > t_stop + timeout_ns + 0.01e9 + 1]
    assert late == [] and node.core.state == MavrosState.FAILED
    _, st = messages.status_from_diagnostic_array(status[-1])
    assert st[0].values["transport"] == "mavros" and st[0].values["state"] == "FAILED"
    assert any(
        "stale input" in messages.status_from_diagnostic_array(s)[1][0].message for s in status
    )


def test_node_mavros_rejects_wrong_frame_and_republishes_imu(fresh):
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu

    from lpv_sysid.nodes.mavlink_bridge_node import MavlinkBridgeNode

    rclpy.init(args=ros_args(("transport", "mavros"), ("mavros.interfaces", "common")))
    node = MavlinkBridgeNode(namespace=NS)
    mavros = rclpy.create_node("mavros")
    f = messages.MsgFactory.rclpy()
    e = [0.05, -0.1, 1.2]
    pub_odom = mavros.create_publisher(
        Odometry, "/mavros/local_position/odom", qos_profile_sensor_data
    )
    pub_imu = mavros.create_publisher(Imu, "/mavros/imu/data", qos_profile_sensor_data)
    states, imus, status = [], [], []
    mavros.create_subscription(
        Odometry, "/lpv_sysid/state", states.append, qos_profile_sensor_data
    )
    mavros.create_subscription(Imu, "/lpv_sysid/imu", imus.append, qos_profile_sensor_data)
    mavros.create_subscription(DiagnosticArray, "/lpv_sysid/status", status.append, 100)
    pub_odom.publish(
        messages.odometry_from_state(f, 10**9, [0, 0, 0], e, [0, 0, 0], [0, 0, 0], frame_id="odom")
    )  # MAVROS configured otherwise
    pub_imu.publish(messages.imu_msg(f, 10**9, [0.3, -0.2, -9.7], [0.01, 0.02, -0.03], e))
    try:
        spin([node, mavros], 0.1)
    finally:
        node.destroy_node()
    assert states == [] and node.core.rejected_inputs == 1
    msgs = [messages.status_from_diagnostic_array(s)[1][0] for s in status]
    assert any(
        s.level == 2
        and "/mavros/local_position/odom rejected" in s.message
        and "expected frame_id 'map'" in s.message
        for s in msgs
    )
    (imu,) = imus
    back = messages.imu_from_msg(imu)
    np.testing.assert_allclose(back.specific_force, [0.3, -0.2, -9.7], atol=1e-12)
    np.testing.assert_allclose(back.omega, [0.01, 0.02, -0.03], atol=1e-12)
    np.testing.assert_allclose(back.euler, e, atol=1e-12)
