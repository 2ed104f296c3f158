"""ROS conventions of the node graph (issue 24 item 3), through the rclpy stand-in (real
Jazzy: test_ros_real.py): a namespace per vehicle with no crosstalk, ``status`` transient
local, the documented QoS both on the wire and in a recording's ``offered_qos_profiles``,
the REP-105 transform odom -> base_link on /tf from the state, and the rotor-speed source
in the joint names (``header.frame_id`` stays a frame)."""

import os

import numpy as np
import pytest
import rclpy
import rclpy._standin as standin
import yaml
from nav_msgs.msg import Odometry
from rclpy.qos import QoSDurabilityPolicy, QoSReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

from lpv_sysid.io import messages
from lpv_sysid.nodes import shell
from lpv_sysid.nodes.sim_vehicle_node import SimVehicleNode

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "config")


@pytest.fixture(autouse=True)
def fresh():
    standin.reset()
    yield
    rclpy.try_shutdown()


def _args(**params):
    args = ["n", "--ros-args", "--params-file", os.path.join(CONFIG, "sim_vehicle.yaml")]
    for k, v in params.items():
        args += ["-p", f"{k}:={v}"]
    return args


def test_two_namespaced_vehicles_share_no_topic():
    """Two simulated vehicles in ``uav1`` and ``uav2`` (the launch files' ``namespace``
    argument): every topic of each is under its namespace, and a subscriber of one
    vehicle's state receives exactly that vehicle's samples."""
    from rclpy.parameter import Parameter

    rclpy.init(args=_args())
    fwd = Parameter("initial_velocity_frd", Parameter.Type.DOUBLE_ARRAY, [1.0, 0.0, 0.0])
    a = SimVehicleNode(namespace="uav1", parameter_overrides=[fwd])
    b = SimVehicleNode(namespace="uav2")
    probe = rclpy.create_node("probe")
    got = {ns: [] for ns in ("uav1", "uav2")}
    for ns in got:
        probe.create_subscription(
            Odometry, f"/{ns}/state", got[ns].append, qos_profile_sensor_data
        )
    standin.spin_nodes([a, b, probe], 1.0)
    for node, ns in ((a, "uav1"), (b, "uav2")):
        names = {e.topic_name for e in [*node.publishers, *node.subscriptions]}
        mine = {n for n in names if n.startswith(f"/{ns}/")}
        # absolute by convention: /diagnostics (names carry the namespace), nothing else
        assert names - mine == {"/diagnostics"}, names
        assert {f"/{ns}/{t}" for t in ("state", "imu", "rotor_speeds", "status")} <= mine
    assert len(got["uav1"]) == len(got["uav2"]) == 250  # 250 Hz each, none of the other's
    # uav1 flies 1 m/s forward, uav2 hovers: the streams are not mixed
    v1 = [messages.state_from_odometry(m).v_body[0] for m in got["uav1"]]
    v2 = [messages.state_from_odometry(m).v_body[0] for m in got["uav2"]]
    assert np.mean(v1) == pytest.approx(1.0, abs=0.05) and abs(np.mean(v2)) < 0.05


def test_publishers_offer_the_documented_qos():
    """Sensor streams best effort (rclpy's sensor-data profile), status transient local and
    reliable: the README's table (io/messages/topics.py is its one declaration)."""
    rclpy.init(args=_args())
    node = SimVehicleNode()
    for topic in ("state", "imu", "rotor_speeds"):
        q = standin.find_publisher(node, topic).qos_profile
        assert q.reliability == QoSReliabilityPolicy.BEST_EFFORT and q.depth == 5
        assert q.reliability == qos_profile_sensor_data.reliability
        assert q.depth == qos_profile_sensor_data.depth
    for topic in ("status", "/diagnostics"):
        q = standin.find_publisher(node, topic).qos_profile
        assert q.reliability == QoSReliabilityPolicy.RELIABLE
        assert q.durability == QoSDurabilityPolicy.TRANSIENT_LOCAL and 1 <= q.depth <= 10
    readme = open(os.path.join(ROOT, "README.md")).read()
    assert "best effort, keep last 5" in readme and "reliable and transient local" in readme
    node.destroy_node()


def test_a_recording_stores_the_offered_qos(tmp_path):
    """The data logger's bags carry each topic's offered QoS as published (rosbag2's
    metadata.yaml, read back as text): ``ros2 bag play`` offers best effort sensor data and
    a transient-local status again."""
    from lpv_sysid.io.recorder import Recorder, RecorderConfig

    topics = {f"/uav7/{n}": t for n, t in messages.TYPES.items()}
    rec = Recorder(RecorderConfig(out_dir=str(tmp_path / "exp"), topics=topics))
    rec.start(1_000_000_000)
    rec.stop(2_000_000_000)
    meta = yaml.safe_load((tmp_path / "exp" / "bag_0000" / "metadata.yaml").read_text())
    offered = {}
    for t in meta["rosbag2_bagfile_information"]["topics_with_message_count"]:
        q = t["topic_metadata"]["offered_qos_profiles"]
        q = yaml.safe_load(q) if isinstance(q, str) else q
        offered[t["topic_metadata"]["name"].rsplit("/", 1)[1]] = q[0]
    for n in ("state", "imu", "rotor_speeds"):
        assert offered[n]["reliability"] == "best_effort" and offered[n]["depth"] == 5, n
    for n in ("velocity_reference", "excitation", "actuator_command"):
        assert offered[n]["reliability"] == "reliable", n
        assert offered[n]["durability"] == "volatile", n
    assert offered["status"]["reliability"] == "reliable"
    assert offered["status"]["durability"] == "transient_local"


def test_tf_odom_to_base_link_follows_the_state_when_enabled():
    """``publish_tf: true``: one transform odom -> base_link per state sample on /tf, with
    the state's stamp, ENU position and orientation (REP-105); off by default."""
    rclpy.init(args=_args(initial_velocity_frd="[2.0, 1.0, 0.0]", publish_tf="true"))
    node = SimVehicleNode()
    probe = rclpy.create_node("probe")
    states, tfs = [], []
    probe.create_subscription(Odometry, "/lpv_sysid/state", states.append, qos_profile_sensor_data)
    probe.create_subscription(TFMessage, "/tf", tfs.append, 100)
    standin.spin_nodes([node, probe], 0.5)
    assert len(tfs) == len(states) == 125
    for tf, st in zip(tfs, states):
        (t,) = tf.transforms
        assert (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")
        assert t.header.stamp == st.header.stamp
        p, q = st.pose.pose.position, st.pose.pose.orientation
        tr, rot = t.transform.translation, t.transform.rotation
        assert (tr.x, tr.y, tr.z) == (p.x, p.y, p.z)
        assert (rot.x, rot.y, rot.z, rot.w) == (q.x, q.y, q.z, q.w)
    # flying forward (FRD u = 2 m/s, v = 1 m/s at yaw 0: north/east) moves base_link in ENU
    # x = east, y = north
    first, last = tfs[0].transforms[0].transform, tfs[-1].transforms[0].transform
    dt = (
        tfs[-1].transforms[0].header.stamp.nanosec - tfs[0].transforms[0].header.stamp.nanosec
    ) * 1e-9
    dt += tfs[-1].transforms[0].header.stamp.sec - tfs[0].transforms[0].header.stamp.sec
    assert last.translation.y - first.translation.y == pytest.approx(2.0 * dt, rel=0.05)
    assert last.translation.x - first.translation.x == pytest.approx(1.0 * dt, rel=0.05)
    probe.destroy_node()
    node.destroy_node()
    rclpy.try_shutdown()
    standin.reset()
    rclpy.init(args=_args())
    node = SimVehicleNode()
    assert standin.find_publisher(node, "/tf") is None  # off by default


def test_rotor_speed_source_is_in_the_names_not_the_frame():
    rclpy.init(args=_args())
    node = SimVehicleNode()
    probe = rclpy.create_node("probe")
    got = []
    probe.create_subscription(
        JointState, "/lpv_sysid/rotor_speeds", got.append, qos_profile_sensor_data
    )
    standin.spin_nodes([node, probe], 0.1)
    assert got and all(m.header.frame_id == messages.BASE_FRAME for m in got)
    assert list(got[0].name) in (list(messages.ROTOR_NAMES), list(messages.ROTOR_ESTIMATED_NAMES))
    assert shell.qos_for("rotor_speeds").reliability == QoSReliabilityPolicy.BEST_EFFORT
