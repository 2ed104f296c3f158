"""lpv_controller_node through the stand-in: gains validation, wiring, end-to-end flow
excitation -> controller -> sim vehicle -> logger, and every safety abort path."""

import math
import os

import numpy as np
import pytest
import rclpy
import rclpy._standin as standin
from rclpy._standin import call_trigger as call, spin_nodes as spin
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from lpv_test_gains import gains_dict, write_gains
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from lpv_sysid.io import messages as M
from lpv_sysid.io.bag import read_bag
from lpv_sysid.signals.store import save_npz

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "config")


@pytest.fixture(autouse=True)
def fresh():
    standin.reset()
    yield
    rclpy.try_shutdown()


@pytest.fixture(scope="module")
def gains(tmp_path_factory):
    return write_gains(tmp_path_factory.mktemp("g") / "gains.yaml")


@pytest.fixture(scope="module")
def signals2(tmp_path_factory):
    """Phase-2 table: v_d = 0.8 sin(2 pi 0.2 t) on u_d, four sines on u_e (amplitude 0.5)."""
    t = np.arange(0.0, 20.0, 0.02)
    cols = [0.8 * np.sin(2 * np.pi * 0.2 * t), 0 * t, 0 * t] + \
        [0.5 * np.sin(2 * np.pi * f * t) for f in (1.3, 1.7, 2.3, 2.9)]
    path = str(tmp_path_factory.mktemp("s") / "sig2.npz")
    save_npz(path, t, np.stack(cols, axis=1),
             ["u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r"])
    return path


def args(params_file, **params):
    a = ["--ros-args", "--params-file", os.path.join(CONFIG, params_file)]
    for k, v in params.items():
        a += ["-p", f"{k}:={v}"]
    return a


def graph(gains, signals2, tmp_path, controller_start=True, **ctrl):
    from lpv_sysid.nodes.data_logger_node import DataLoggerNode
    from lpv_sysid.nodes.excitation_node import ExcitationNode
    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode
    from lpv_sysid.nodes.sim_vehicle_node import SimVehicleNode
    rclpy.init()
    return {
        "sim": SimVehicleNode(cli_args=args("sim_vehicle.yaml", mode="lpv")),
        "exc": ExcitationNode(cli_args=args("excitation_node.yaml", signals_file=signals2,
                                            mode="phase2", ramp_s=1.0, auto_start=True)),
        "ctl": LpvControllerNode(cli_args=args("lpv_controller.yaml", gains_file=gains,
                                               auto_start=controller_start, **ctrl)),
        "log": DataLoggerNode(cli_args=args("data_logger.yaml", out_dir=str(tmp_path / "log"))),
        "probe": rclpy.create_node("probe"),
    }




def statuses(msgs, name="/lpv_sysid/lpv_controller"):
    out = []
    for m in msgs:
        _, st = M.status_from_diagnostic_array(m)
        out += [s for s in st if s.name == name]
    return out


def test_controller_wiring(gains):
    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode
    rclpy.init()
    node = LpvControllerNode(cli_args=args("lpv_controller.yaml", gains_file=gains))
    topics = dict(node.get_topic_names_and_types())
    assert topics == {"/lpv_sysid/state": ["nav_msgs/msg/Odometry"],
                      "/lpv_sysid/rotor_speeds": ["sensor_msgs/msg/JointState"],
                      "/lpv_sysid/velocity_reference": ["geometry_msgs/msg/TwistStamped"],
                      "/lpv_sysid/excitation": ["sensor_msgs/msg/JointState"],
                      "/lpv_sysid/actuator_command": ["sensor_msgs/msg/JointState"],
                      "/lpv_sysid/status": ["diagnostic_msgs/msg/DiagnosticArray"]}
    rel = QoSReliabilityPolicy
    assert standin.find_subscription(node, "state").qos_profile.reliability == rel.BEST_EFFORT
    assert standin.find_subscription(node, "excitation").qos_profile.reliability == rel.RELIABLE
    assert standin.find_publisher(node, "actuator_command").qos_profile.reliability == rel.RELIABLE
    assert node.get_parameter("rate_hz").value == 250.0
    assert node.describe_parameter("state_timeout_s").floating_point_range[0].to_value == 10.0
    assert [n for n, _ in node.get_service_names_and_types()] == [
        "/lpv_sysid/lpv_controller/abort", "/lpv_sysid/lpv_controller/start"]
    # not started: no commands, status says so
    probe = rclpy.create_node("probe")
    st = []
    probe.create_subscription(DiagnosticArray, "/lpv_sysid/status", st.append, 10)
    cmds = []
    probe.create_subscription(JointState, "/lpv_sysid/actuator_command", cmds.append, 10)
    spin([node, probe], 1.0)
    assert cmds == [] and statuses(st)[-1].message.startswith("waiting for start")


@pytest.mark.parametrize("edit, field", [
    (lambda d: d["vertices"][3].update(K=[[0.0] * 12] * 3), "vertices[3].K"),
    (lambda d: d["states"][2].update(name="speed"), "states"),
    (lambda d: d.update(gamma=-1.0), "gamma"),
    (lambda d: d["scheduling"].update(max=[2.0, 2.0, -3.0]), "scheduling"),
])
def test_controller_refuses_invalid_gains(tmp_path, caplog, edit, field):
    from lpv_sysid.nodes import lpv_controller_node
    d = gains_dict()
    edit(d)
    bad = tmp_path / "bad_gains.yaml"
    bad.write_text(yaml.safe_dump(d))
    with caplog.at_level("CRITICAL"):
        code = lpv_controller_node.main(args=["n"] + args("lpv_controller.yaml",
                                                            gains_file=str(bad)))
    assert code == 2
    msg = caplog.records[-1].getMessage()
    assert field in msg and "bad_gains.yaml" in msg


def test_controller_refuses_missing_gains_file(caplog):
    from lpv_sysid.nodes import lpv_controller_node
    with caplog.at_level("CRITICAL"):
        assert lpv_controller_node.main(args=["n", "--ros-args", "-p", "gains_file:=''"]) == 2
    assert "gains_file" in caplog.records[-1].getMessage()


def test_end_to_end_flow_and_tracking(gains, signals2, tmp_path):
    g = graph(gains, signals2, tmp_path)
    probe = g["probe"]
    states = []
    probe.create_subscription(Odometry, "/lpv_sysid/state", states.append,
                              qos_profile_sensor_data)
    refs = []
    probe.create_subscription(TwistStamped, "/lpv_sysid/velocity_reference", refs.append, 100)
    spin(list(g.values()), 4.0)
    ctl = g["ctl"].runtime
    assert ctl.supervisor.event is None and not g["sim"].handed_back
    sent = standin.find_publisher(g["ctl"], "actuator_command").standin_published
    assert sent == ctl.commands > 950          # 250 Hz for ~4 s (first tick waits for inputs)
    g["log"].destroy_node()
    bag = read_bag(str(tmp_path / "log" / "bag_0000"))
    assert len(bag["/lpv_sysid/actuator_command"]) == sent
    assert len(bag["/lpv_sysid/state"]) == 1000 and len(bag["/lpv_sysid/excitation"]) == 400
    # the vehicle follows v_d under the LPV law: forward speed error over the last 2 s
    v = np.array([M.state_from_odometry(m).v_body[0] for m in states[-500:]])
    t_v = np.array([M.stamp_ns_of(m) for m in states[-500:]])
    t_r = np.array([M.stamp_ns_of(m) for m in refs])
    vd = np.interp(t_v, t_r, [M.reference_from_twist(m)[1][0] for m in refs])
    rms = lambda a: np.sqrt(np.mean(a ** 2))  # noqa: E731
    assert np.ptp(vd) > 0.5 and np.corrcoef(v, vd)[0, 1] > 0.9
    assert rms(v - vd) < 0.5 * rms(vd)       # far better than not tracking at all


def _abort_case(gains, signals2, tmp_path, action, **ctrl):
    g = graph(gains, signals2, tmp_path, **ctrl)
    probe = g["probe"]
    st, cmds = [], []
    probe.create_subscription(DiagnosticArray, "/lpv_sysid/status", st.append, 100)
    probe.create_subscription(JointState, "/lpv_sysid/actuator_command", cmds.append, 100)
    nodes = list(g.values())
    spin(nodes, 1.0)
    assert g["ctl"].runtime.supervisor.event is None
    action(g, nodes)
    spin(nodes, 1.0)
    errors = [s for s in statuses(st) if s.level == 2]
    ev = g["ctl"].runtime.supervisor.event
    assert ev is not None and errors and errors[0].values["reason"] == ev.reason
    assert errors[0].values["commanding"] == "false"
    # no command stamped after the abort; the vehicle falls back to the PX4-like hold
    assert max(M.stamp_ns_of(c) for c in cmds) <= ev.t * 1e9
    if g["sim"] in nodes:
        assert g["sim"].handed_back
    return ev


def test_abort_on_stale_state(gains, signals2, tmp_path):
    def stop_sim(g, nodes):
        nodes.remove(g["sim"])      # the state stream stops (estimator/link failure)
    ev = _abort_case(gains, signals2, tmp_path, stop_sim)
    assert ev.reason == "stale" and ev.detail.startswith(("state", "rotor_speeds"))


def test_abort_service(gains, signals2, tmp_path):
    def call_abort(g, nodes):
        cli = g["probe"].create_client(Trigger, "/lpv_sysid/lpv_controller/abort")
        fut = cli.call_async(Trigger.Request())
        ex = SingleThreadedExecutor()
        for n in nodes:
            ex.add_node(n)
        ex.spin_until_future_complete(fut, timeout_sec=0.1)
        assert fut.result().success
    ev = _abort_case(gains, signals2, tmp_path, call_abort)
    assert ev.reason == "external"


def test_abort_on_nan_state(gains, signals2, tmp_path):
    def inject_nan(g, nodes):
        pub = g["probe"].create_publisher(Odometry, "/lpv_sysid/state", qos_profile_sensor_data)
        msg = Odometry()
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.header.stamp = g["probe"].get_clock().now().to_msg()
        msg.pose.pose.orientation.w = 1.0
        msg.twist.twist.linear.x = math.nan
        pub.publish(msg)
    ev = _abort_case(gains, signals2, tmp_path, inject_nan)
    assert ev.reason == "non_finite" and "state" in ev.detail


def test_abort_outside_scheduling_box(gains, signals2, tmp_path):
    def big_reference(g, nodes):
        pub = g["probe"].create_publisher(TwistStamped, "/lpv_sysid/velocity_reference", 10)
        stamp = g["probe"].get_clock().now().nanoseconds + 5_000_000
        pub.publish(M.twist_reference_msg(M.MsgFactory.rclpy(), stamp, [3.0, 0.0, 0.0]))
    ev = _abort_case(gains, signals2, tmp_path, big_reference)
    assert ev.reason == "out_of_box" and ev.detail.startswith("scheduling[0] = 3")
