"""rclpy behaviours the node shells meet, as {case: outcome} JSON on stdout.

Run once with a real rclpy (under ``ROS_PYTHON_CHECK_FIELDS=1``, which the real-ROS tests
set for every node too) and once with the in-repo stand-in (test/support first on the
path); test_ros_real.py requires the same outcomes, so the stand-in is no kinder than
rclpy in any case listed here (an exception is compared by its type, messages differ in
wording). ``python rclpy_probe.py WORKDIR`` (parameter files are written there).
"""

import json
import math
import sys

import rclpy
from rclpy.parameter import Parameter

OUT = {}


def outcome(fn):
    """``ok <value>`` or the exception's type (messages differ in wording only)."""
    try:
        r = fn()
        return f"ok {r!r}" if r is not None else "ok"
    except Exception as exc:
        return type(exc).__name__


def case(name, params_file=None, args=()):
    def deco(fn):
        argv = ["probe", "--ros-args", *args]
        if params_file:
            with open(sys.argv[1] + f"/{name}.yaml", "w") as f:
                f.write(params_file)
            argv += ["--params-file", sys.argv[1] + f"/{name}.yaml"]
        rclpy.init(args=argv)
        try:
            node = rclpy.create_node("probe")
            OUT[name] = outcome(lambda: fn(node))
        finally:
            rclpy.try_shutdown()
        return fn

    return deco


@case("log_severity_changes_at_one_call_site")
def _(node):
    log = node.get_logger()
    for level in ("info", "error"):
        {"info": log.info, "error": log.error}[level]("x")


@case("log_two_severities_two_call_sites")
def _(node):
    log = node.get_logger()
    for level in ("info", "error"):
        if level == "info":
            log.info("x")
        else:
            log.error("x")


@case("log_filter_changes_at_one_call_site")
def _(node):
    for once in (True, False):
        node.get_logger().warning("x", once=once)


@case("log_unknown_keyword")
def _(node):
    node.get_logger().info("x", bogus=1)


@case("publish_after_context_shutdown")
def _(node):
    from std_msgs.msg import String

    pub = node.create_publisher(String, "t", 10)
    rclpy.shutdown()
    pub.publish(String())


@case("publish_wrong_type")
def _(node):
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    node.create_publisher(String, "t", 10).publish(JointState())


@case("double_parameter_from_integer_in_file", "/**/probe:\n  ros__parameters:\n    x: 1\n")
def _(node):
    node.declare_parameter("x", 0.5)


@case("parameter_out_of_range_from_file", "/**/probe:\n  ros__parameters:\n    x: 5.0\n")
def _(node):
    from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor

    node.declare_parameter(
        "x",
        0.5,
        ParameterDescriptor(
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=1.0, step=0.0)]
        ),
    )


@case("typed_parameter_without_default")
def _(node):
    p = node.declare_parameter("x", Parameter.Type.DOUBLE_ARRAY)
    return (p.type_.name, outcome(lambda: node.get_parameter("x")))


@case("empty_list_default_type")
def _(node):
    return node.declare_parameter("x", []).type_.name


@case("empty_list_in_file", "/**/probe:\n  ros__parameters:\n    x: []\n")
def _(node):
    return node.declare_parameter("x", Parameter.Type.STRING_ARRAY).type_.name


@case("typed_empty_list_set")
def _(node):
    node.declare_parameter("x", Parameter.Type.STRING_ARRAY)
    (r,) = node.set_parameters([Parameter("x", Parameter.Type.STRING_ARRAY, [])])
    p = node.get_parameter("x")
    return (r.successful, p.type_.name, list(p.value))


@case("nan_in_file", "/**/probe:\n  ros__parameters:\n    x: .nan\n")
def _(node):
    return math.isnan(node.declare_parameter("x", 1.0).value)


@case("nested_names_in_file", "/**/probe:\n  ros__parameters:\n    a:\n      b: 2.0\n")
def _(node):
    return node.declare_parameter("a.b", 1.0).value


@case("int_array_from_file", "/**/probe:\n  ros__parameters:\n    x: [1, 2]\n")
def _(node):
    p = node.declare_parameter("x", [0])
    return (p.type_.name, type(p.value).__name__, list(p.value))


@case("string_override_for_bool", args=["-p", "x:=yes"])
def _(node):
    return node.declare_parameter("x", False).value


@case("timer_callback_exception_propagates")
def _(node):
    from rclpy.executors import SingleThreadedExecutor

    def boom():
        raise RuntimeError("boom")

    node.create_timer(0.001, boom)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    for _ in range(100):
        ex.spin_once(timeout_sec=0.01)


@case("float_field_from_int_list")
def _(node):
    from sensor_msgs.msg import JointState

    m = JointState()
    m.position = [1, 2]
    return list(m.position)


@case("stamp_sec_from_numpy_int64")
def _(node):
    import numpy as np
    from builtin_interfaces.msg import Time

    Time().sec = np.int64(1)


@case("diagnostic_level_int")
def _(node):
    from diagnostic_msgs.msg import DiagnosticStatus

    DiagnosticStatus().level = 0


@case("keyvalue_value_float")
def _(node):
    from diagnostic_msgs.msg import KeyValue

    KeyValue().value = 1.0


@case("float_field_from_numpy_float")
def _(node):
    import numpy as np
    from geometry_msgs.msg import Vector3

    v = Vector3()
    v.x = np.float64(1.5)
    return float(v.x)  # the value kept (numpy 2 prints np.float64(1.5))


@case("init_twice")
def _(node):
    rclpy.init()


@case("invalid_topic_name")
def _(node):
    from std_msgs.msg import String

    node.create_publisher(String, "a b", 10)


@case("info_enabled_by_default")
def _(node):
    from rclpy.logging import LoggingSeverity

    return node.get_logger().is_enabled_for(LoggingSeverity.INFO)


@case("empty_list_in_file_over_a_default", "/**/probe:\n  ros__parameters:\n    x: []\n")
def _(node):
    return node.declare_parameter("x", ["a"]).type_.name


@case("null_in_file_for_a_double", "/**/probe:\n  ros__parameters:\n    x: null\n")
def _(node):
    node.declare_parameter("x", 1.0)


@case("publish_after_destroy_publisher")
def _(node):
    from std_msgs.msg import String

    pub = node.create_publisher(String, "t", 10)
    node.destroy_publisher(pub)
    pub.publish(String())


@case("get_undeclared_parameter")
def _(node):
    node.get_parameter("nope")


@case("spin_once_after_shutdown")
def _(node):
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor()
    ex.add_node(node)
    rclpy.shutdown()
    ex.spin_once(timeout_sec=0.01)


@case("init_after_shutdown")
def _(node):
    rclpy.shutdown()
    rclpy.init()
    return rclpy.ok()


print(json.dumps(OUT, indent=1, sort_keys=True))
