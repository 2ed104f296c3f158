"""The rclpy stand-in itself: Jazzy signatures, parameter typing, QoS matching, timers.

The signature table below is written from the ROS 2 Jazzy rclpy API (rclpy 7.1,
docs.ros.org/en/jazzy/p/rclpy); the stand-in must match it parameter for parameter
(names, kinds, defaults) so shells that run here run on a robot.
"""

import inspect

import numpy as np
import pytest
import rclpy
import rclpy._standin as standin
from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Vector3
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    QoSDurabilityPolicy,
    QoSHistoryPolicy,
    QoSProfile,
    QoSReliabilityPolicy,
    qos_profile_sensor_data,
)
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

P, K = inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY
E = inspect.Parameter.empty

# (callable, [(name, kind, default)]) -- Jazzy signatures; "ANY" = default not compared
JAZZY = {
    "rclpy.init": (
        rclpy.init,
        [
            ("args", P, None),
            ("context", K, None),
            ("domain_id", K, None),
            ("signal_handler_options", K, None),
        ],
    ),
    "rclpy.spin": (rclpy.spin, [("node", P, E), ("executor", P, None)]),
    "rclpy.spin_once": (
        rclpy.spin_once,
        [("node", P, E), ("executor", K, None), ("timeout_sec", K, None)],
    ),
    "rclpy.spin_until_future_complete": (
        rclpy.spin_until_future_complete,
        [("node", P, E), ("future", P, E), ("executor", P, None), ("timeout_sec", P, None)],
    ),
    "rclpy.shutdown": (rclpy.shutdown, [("context", K, None), ("uninstall_handlers", K, None)]),
    "rclpy.try_shutdown": (
        rclpy.try_shutdown,
        [("context", K, None), ("uninstall_handlers", K, None)],
    ),
    "rclpy.ok": (rclpy.ok, [("context", K, None)]),
    "Node.__init__": (
        Node.__init__,
        [
            ("self", P, E),
            ("node_name", P, E),
            ("context", K, None),
            ("cli_args", K, None),
            ("namespace", K, None),
            ("use_global_arguments", K, True),
            ("enable_rosout", K, True),
            ("start_parameter_services", K, True),
            ("parameter_overrides", K, None),
            ("allow_undeclared_parameters", K, False),
            ("automatically_declare_parameters_from_overrides", K, False),
            ("enable_logger_service", K, False),
        ],
    ),
    "Node.declare_parameter": (
        Node.declare_parameter,
        [
            ("self", P, E),
            ("name", P, E),
            ("value", P, None),
            ("descriptor", P, None),
            ("ignore_override", P, False),
        ],
    ),
    "Node.declare_parameters": (
        Node.declare_parameters,
        [("self", P, E), ("namespace", P, E), ("parameters", P, E), ("ignore_override", P, False)],
    ),
    "Node.get_parameter": (Node.get_parameter, [("self", P, E), ("name", P, E)]),
    "Node.set_parameters": (Node.set_parameters, [("self", P, E), ("parameter_list", P, E)]),
    "Node.add_on_set_parameters_callback": (
        Node.add_on_set_parameters_callback,
        [("self", P, E), ("callback", P, E)],
    ),
    "Node.add_post_set_parameters_callback": (
        Node.add_post_set_parameters_callback,
        [("self", P, E), ("callback", P, E)],
    ),
    "Node.create_publisher": (
        Node.create_publisher,
        [
            ("self", P, E),
            ("msg_type", P, E),
            ("topic", P, E),
            ("qos_profile", P, E),
            ("callback_group", K, None),
            ("event_callbacks", K, None),
            ("qos_overriding_options", K, None),
            ("publisher_class", K, "ANY"),
        ],
    ),
    "Node.create_subscription": (
        Node.create_subscription,
        [
            ("self", P, E),
            ("msg_type", P, E),
            ("topic", P, E),
            ("callback", P, E),
            ("qos_profile", P, E),
            ("callback_group", K, None),
            ("event_callbacks", K, None),
            ("qos_overriding_options", K, None),
            ("raw", K, False),
        ],
    ),
    "Node.create_timer": (
        Node.create_timer,
        [
            ("self", P, E),
            ("timer_period_sec", P, E),
            ("callback", P, E),
            ("callback_group", P, None),
            ("clock", P, None),
            ("autostart", P, True),
        ],
    ),
    "Node.create_service": (
        Node.create_service,
        [
            ("self", P, E),
            ("srv_type", P, E),
            ("srv_name", P, E),
            ("callback", P, E),
            ("qos_profile", K, "ANY"),
            ("callback_group", K, None),
        ],
    ),
    "Node.create_client": (
        Node.create_client,
        [
            ("self", P, E),
            ("srv_type", P, E),
            ("srv_name", P, E),
            ("qos_profile", K, "ANY"),
            ("callback_group", K, None),
        ],
    ),
    "Node.destroy_node": (Node.destroy_node, [("self", P, E)]),
    "Node.get_logger": (Node.get_logger, [("self", P, E)]),
    "Node.get_clock": (Node.get_clock, [("self", P, E)]),
    "SingleThreadedExecutor.spin_once": (
        SingleThreadedExecutor.spin_once,
        [("self", P, E), ("timeout_sec", P, None)],
    ),
    "Parameter.__init__": (
        Parameter.__init__,
        [("self", P, E), ("name", P, E), ("type_", P, None), ("value", P, None)],
    ),
}


@pytest.fixture(autouse=True)
def fresh_context():
    standin.reset()
    yield
    rclpy.try_shutdown()


@pytest.mark.parametrize("name", sorted(JAZZY))
def test_signatures_match_jazzy(name):
    func, expected = JAZZY[name]
    got = [(p.name, p.kind, p.default) for p in inspect.signature(func).parameters.values()]
    assert [(n, k) for n, k, _ in got] == [(n, k) for n, k, _ in expected]
    for (n, _, d_got), (_, _, d_exp) in zip(got, expected):
        if d_exp != "ANY":
            assert d_got == d_exp, f"{name}: default of {n}"


def test_init_returns_none_and_lifecycle():
    assert rclpy.init() is None
    assert rclpy.ok()
    with pytest.raises(RuntimeError):
        rclpy.init()
    rclpy.shutdown()
    assert not rclpy.ok()
    with pytest.raises(RuntimeError):
        rclpy.shutdown()
    rclpy.try_shutdown()  # no error


def test_node_requires_init_and_validates_names():
    from rclpy.exceptions import (
        InvalidNodeNameException,
        InvalidTopicNameException,
        NotInitializedException,
    )

    with pytest.raises(NotInitializedException):
        Node("x")
    rclpy.init()
    with pytest.raises(InvalidNodeNameException):
        Node("bad-name")
    n = Node("ctl", namespace="lpv_sysid")
    assert n.get_namespace() == "/lpv_sysid" and n.get_name() == "ctl"
    assert n.resolve_topic_name("state") == "/lpv_sysid/state"
    assert n.resolve_topic_name("~/diag") == "/lpv_sysid/ctl/diag"
    assert n.resolve_topic_name("/abs") == "/abs"
    with pytest.raises(InvalidTopicNameException):
        n.create_publisher(Float64, "1bad", 10)


def test_message_defaults_and_rclpy_field_checks():
    o = Odometry()
    assert o.pose.covariance.shape == (36,) and o.pose.covariance.dtype == np.float64
    assert o.header.stamp == TimeMsg(sec=0, nanosec=0) and o.child_frame_id == ""
    with pytest.raises(AssertionError):
        Vector3(x=1)  # rclpy float fields refuse int
    with pytest.raises(AssertionError):
        JointState(position=np.array([1.0]))  # numpy array is not a Sequence for rclpy
    with pytest.raises(AssertionError):
        TimeMsg(sec=0, nanosec=-1)  # uint32 range
    with pytest.raises(AssertionError):
        Odometry(bogus=1)
    assert DiagnosticStatus.ERROR == b"\x02"
    js = JointState(name=["a", "b"], position=[1.0, 2.5])
    assert list(js.position) == [1.0, 2.5]


def test_serialization_identical_to_rosbags_cdr():
    js = JointState(name=["ut", "ua"], position=[0.25, -1.5])
    js.header.stamp = TimeMsg(sec=12, nanosec=345)
    data = serialize_message(js)
    ts = get_typestore(Stores.ROS2_JAZZY)
    rb = ts.deserialize_cdr(data, "sensor_msgs/msg/JointState")
    assert rb.name == ["ut", "ua"] and rb.position.tolist() == [0.25, -1.5]
    assert rb.header.stamp.sec == 12 and rb.header.stamp.nanosec == 345
    assert bytes(ts.serialize_cdr(rb, "sensor_msgs/msg/JointState")) == data
    assert deserialize_message(data, JointState) == js


def test_parameter_typing_rules():
    rclpy.init()
    n = Node("p")
    desc = ParameterDescriptor(
        description="gain",
        floating_point_range=[FloatingPointRange(from_value=0.0, to_value=10.0, step=0.0)],
    )
    assert n.declare_parameter("gain", 1.0, desc).value == 1.0
    assert n.get_parameter("gain").type_ == Parameter.Type.DOUBLE
    # int for a double parameter fails, as in Jazzy
    res = n.set_parameters([Parameter("gain", value=2)])
    assert not res[0].successful and "Wrong parameter type" in res[0].reason
    assert n.get_parameter("gain").value == 1.0
    res = n.set_parameters([Parameter("gain", value=20.0)])
    assert not res[0].successful and "out of range" in res[0].reason
    assert n.set_parameters([Parameter("gain", value=10.0)])[0].successful
    assert n.get_parameter("gain").value == 10.0
    n.declare_parameter(
        "rate",
        100,
        ParameterDescriptor(integer_range=[IntegerRange(from_value=1, to_value=1000, step=1)]),
    )
    assert not n.set_parameters([Parameter("rate", value=0)])[0].successful
    # empty list default infers BYTE_ARRAY (a Jazzy pitfall the shells must avoid)
    assert n.declare_parameter("names", []).type_ == Parameter.Type.BYTE_ARRAY
    from rclpy.exceptions import (
        ParameterAlreadyDeclaredException,
        ParameterNotDeclaredException,
        ParameterUninitializedException,
    )

    with pytest.raises(ParameterAlreadyDeclaredException):
        n.declare_parameter("gain", 3.0)
    with pytest.raises(ParameterNotDeclaredException):
        n.get_parameter("nope")
    n.declare_parameter("later", Parameter.Type.STRING)
    with pytest.raises(ParameterUninitializedException):
        n.get_parameter("later")
    with pytest.raises(ValueError):
        n.declare_parameter("x", None, ParameterDescriptor())
    seen = []
    n.add_on_set_parameters_callback(
        lambda ps: __import__("rcl_interfaces.msg").msg.SetParametersResult(
            successful=ps[0].value < 5.0, reason="too big"
        )
    )
    n.add_post_set_parameters_callback(lambda ps: seen.append(ps[0].value))
    assert n.set_parameters([Parameter("gain", value=4.0)])[0].successful
    r = n.set_parameters([Parameter("gain", value=6.0)])[0]
    assert not r.successful and r.reason == "too big"
    assert seen == [4.0]


def test_params_file_and_wrong_type_override(tmp_path):
    from rclpy.exceptions import InvalidParameterTypeException

    f = tmp_path / "p.yaml"
    f.write_text(
        "/lpv_sysid/ctl:\n  ros__parameters:\n    rate: 250.0\n    nested:\n"
        "      k: 3\n/**:\n  ros__parameters:\n    common: 'x'\n"
    )
    rclpy.init(args=["prog", "--ros-args", "--params-file", str(f), "-p", "extra:=2.5"])
    n = Node("ctl", namespace="/lpv_sysid")
    assert n.declare_parameter("rate", 100.0).value == 250.0
    assert n.declare_parameter("nested.k", 0).value == 3
    assert n.declare_parameter("common", "").value == "x"
    assert n.declare_parameter("extra", 1.0).value == 2.5
    other = Node("other", parameter_overrides=[Parameter("rate", value=5)])
    with pytest.raises(InvalidParameterTypeException):
        other.declare_parameter("rate", 1.0)  # YAML/override int for a double parameter


def test_qos_profile_rules_and_compatibility():
    from rclpy.qos import InvalidQoSProfileException

    with pytest.raises(InvalidQoSProfileException):
        QoSProfile(reliability=QoSReliabilityPolicy.RELIABLE)
    assert qos_profile_sensor_data.reliability == QoSReliabilityPolicy.BEST_EFFORT
    assert qos_profile_sensor_data.depth == 5
    rclpy.init()
    n = Node("q")
    got = {"rel": [], "be": [], "tl": []}
    pub_be = n.create_publisher(Float64, "be_topic", qos_profile_sensor_data)
    n.create_subscription(Float64, "be_topic", lambda m: got["rel"].append(m.data), 10)
    n.create_subscription(
        Float64, "be_topic", lambda m: got["be"].append(m.data), qos_profile_sensor_data
    )
    pub_rel = n.create_publisher(Float64, "rel_topic", 10)
    n.create_subscription(
        Float64, "rel_topic", lambda m: got["be"].append(10 + m.data), qos_profile_sensor_data
    )
    latched = QoSProfile(depth=1, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)
    pub_tl = n.create_publisher(Float64, "tl_topic", latched)
    pub_tl.publish(Float64(data=7.0))
    n.create_subscription(Float64, "tl_topic", lambda m: got["tl"].append(m.data), latched)
    pub_be.publish(Float64(data=1.0))
    pub_rel.publish(Float64(data=2.0))
    for _ in range(5):
        rclpy.spin_once(n, timeout_sec=0.0)
    assert got["rel"] == []  # reliable sub never hears a best-effort publisher
    assert sorted(got["be"]) == [1.0, 12.0]
    assert got["tl"] == [7.0]  # transient local: late joiner gets the last sample


def test_keep_last_depth_drops_oldest():
    rclpy.init()
    n = Node("d")
    got = []
    pub = n.create_publisher(Float64, "t", qos_profile_sensor_data)
    sub = n.create_subscription(
        Float64, "t", lambda m: got.append(m.data), qos_profile_sensor_data
    )
    for i in range(8):
        pub.publish(Float64(data=float(i)))
    for _ in range(8):
        rclpy.spin_once(n, timeout_sec=0.0)
    assert got == [3.0, 4.0, 5.0, 6.0, 7.0] and sub.standin_dropped == 3
    with pytest.raises(TypeError):
        pub.publish(JointState())


def test_timers_fire_on_simulated_clock():
    rclpy.init()
    n = Node("t")
    stamps = []
    n.create_timer(0.004, lambda: stamps.append(n.get_clock().now().nanoseconds))
    slow = []
    n.create_timer(0.1, lambda: slow.append(n.get_clock().now().nanoseconds))
    ex = SingleThreadedExecutor()
    ex.add_node(n)
    t0 = standin.now_ns()
    standin.spin_for(ex, 1.0)
    assert len(stamps) == 250 and len(slow) == 10
    assert np.all(np.diff(stamps) == 4_000_000)
    assert stamps[0] - t0 == 4_000_000 and slow[-1] - t0 == 1_000_000_000
    msg = n.get_clock().now().to_msg()
    assert msg.sec * 10**9 + msg.nanosec == standin.now_ns()


def test_services_and_spin_until_shutdown():
    rclpy.init()
    n = Node("s", namespace="lpv_sysid")
    calls = []

    def cb(req, resp):
        calls.append(1)
        resp.success = True
        resp.message = "started"
        return resp

    n.create_service(Trigger, "start", cb)
    c = n.create_client(Trigger, "/lpv_sysid/start")
    assert c.wait_for_service(timeout_sec=0.1)
    fut = c.call_async(Trigger.Request())
    rclpy.spin_until_future_complete(n, fut, timeout_sec=1.0)
    assert fut.done() and fut.result().success and fut.result().message == "started"
    assert n.get_service_names_and_types() == [("/lpv_sysid/start", ["std_srvs/srv/Trigger"])]
    n.create_timer(0.5, lambda: calls.append(2))
    standin.shutdown_at(2.0)
    with pytest.raises(ExternalShutdownException):
        rclpy.spin(n)
    assert calls.count(2) == 4 and not rclpy.ok()


def test_history_keep_all_and_logger(caplog):
    rclpy.init()
    n = Node("log", namespace="/lpv_sysid")
    prof = QoSProfile(history=QoSHistoryPolicy.KEEP_ALL)
    got = []
    pub = n.create_publisher(Float64, "k", prof)
    n.create_subscription(Float64, "k", lambda m: got.append(m.data), prof)
    for i in range(50):
        pub.publish(Float64(data=float(i)))
    for _ in range(50):
        rclpy.spin_once(n, timeout_sec=0.0)
    assert len(got) == 50
    with caplog.at_level("INFO"):
        n.get_logger().info("hello")
        for _ in range(3):
            n.get_logger().warning("once", once=True)
    assert [r.name for r in caplog.records] == ["lpv_sysid.log", "lpv_sysid.log"]


def test_raw_subscription_message_lost_and_get_message():
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rosidl_runtime_py.utilities import get_message

    assert get_message("sensor_msgs/msg/JointState") is JointState
    with pytest.raises(ValueError):
        get_message("sensor_msgs/msg/Nope")
    rclpy.init()
    n = Node("raw")
    raw, lost = [], []
    pub = n.create_publisher(JointState, "js", 10)
    sub = n.create_subscription(
        JointState,
        "js",
        raw.append,
        10,
        raw=True,
        event_callbacks=SubscriptionEventCallbacks(message_lost=lambda i: lost.append(i)),
    )
    msg = JointState(name=["a"], position=[0.5])
    pub.publish(msg)
    rclpy.spin_once(n, timeout_sec=0.0)
    assert raw == [serialize_message(msg)] and isinstance(raw[0], bytes)
    sub.standin_lose(3)
    assert lost[0].total_count == 3 and lost[0].total_count_change == 3
