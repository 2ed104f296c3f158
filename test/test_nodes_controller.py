"""lpv_controller_node through the stand-in: gains validation, wiring, end-to-end flow
excitation -> controller -> sim vehicle -> logger, and every safety abort path."""

import math
import os

import numpy as np
import pytest
import rclpy
import rclpy._standin as standin
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from lpv_test_gains import gains_dict, write_gains
from nav_msgs.msg import Odometry
from rclpy._standin import call_trigger as call
from rclpy._standin import spin_nodes as spin
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from lpv_sysid.io import messages
from lpv_sysid.io.bag import read_bag
from lpv_sysid.models.quadrotor import INPUT_NAMES
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
    cols = [0.8 * np.sin(2 * np.pi * 0.2 * t), 0 * t, 0 * t] + [
        0.5 * np.sin(2 * np.pi * f * t) for f in (1.3, 1.7, 2.3, 2.9)
    ]
    path = str(tmp_path_factory.mktemp("s") / "sig2.npz")
    save_npz(
        path, t, np.stack(cols, axis=1), ["u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r"]
    )
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
        "exc": ExcitationNode(
            cli_args=args(
                "excitation_node.yaml",
                signals_file=signals2,
                mode="phase2",
                ramp_s=1.0,
                auto_start=True,
            )
        ),
        "ctl": LpvControllerNode(
            cli_args=args(
                "lpv_controller.yaml", gains_file=gains, auto_start=controller_start, **ctrl
            )
        ),
        "log": DataLoggerNode(cli_args=args("data_logger.yaml", out_dir=str(tmp_path / "log"))),
        "probe": rclpy.create_node("probe"),
    }


def statuses(msgs, name="/lpv_sysid/lpv_controller"):
    out = []
    for m in msgs:
        _, st = messages.status_from_diagnostic_array(m)
        out += [s for s in st if s.name == name]
    return out


def test_controller_wiring(gains):
    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode

    rclpy.init()
    node = LpvControllerNode(cli_args=args("lpv_controller.yaml", gains_file=gains))
    topics = dict(node.get_topic_names_and_types())
    assert topics == {
        "/lpv_sysid/state": ["nav_msgs/msg/Odometry"],
        "/lpv_sysid/rotor_speeds": ["sensor_msgs/msg/JointState"],
        "/lpv_sysid/velocity_reference": ["geometry_msgs/msg/TwistStamped"],
        "/lpv_sysid/excitation": ["sensor_msgs/msg/JointState"],
        "/lpv_sysid/actuator_command": ["sensor_msgs/msg/JointState"],
        "/lpv_sysid/status": ["diagnostic_msgs/msg/DiagnosticArray"],
        "/diagnostics": ["diagnostic_msgs/msg/DiagnosticArray"],
    }
    rel = QoSReliabilityPolicy
    assert standin.find_subscription(node, "state").qos_profile.reliability == rel.BEST_EFFORT
    assert standin.find_subscription(node, "excitation").qos_profile.reliability == rel.RELIABLE
    assert standin.find_publisher(node, "actuator_command").qos_profile.reliability == rel.RELIABLE
    assert node.get_parameter("rate_hz").value == 250.0
    assert node.describe_parameter("state_timeout_s").floating_point_range[0].to_value == 1.0
    assert [n for n, _ in node.get_service_names_and_types()] == [
        "/lpv_sysid/lpv_controller/abort",
        "/lpv_sysid/lpv_controller/start",
    ]
    # not started: no commands, status says so
    probe = rclpy.create_node("probe")
    st = []
    probe.create_subscription(DiagnosticArray, "/lpv_sysid/status", st.append, 10)
    cmds = []
    probe.create_subscription(JointState, "/lpv_sysid/actuator_command", cmds.append, 10)
    spin([node, probe], 1.0)
    assert cmds == [] and statuses(st)[-1].message.startswith("waiting for start")


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda d: d["vertices"][3].update(K=[[0.0] * 12] * 3), "vertices[3].K"),
        # renamed states make no known layout: the structure passes, the (absent) law hash
        # of this uncertified file refuses it first
        (lambda d: d["states"][2].update(name="speed"), "gains_sha256"),
        (lambda d: d.update(gamma=-1.0), "gamma"),
        (lambda d: d["scheduling"].update(max=[2.0, 2.0, -3.0]), "scheduling"),
    ],
)
def test_controller_refuses_invalid_gains(tmp_path, caplog, edit, field):
    from lpv_sysid.nodes import lpv_controller_node

    d = gains_dict()
    edit(d)
    bad = tmp_path / "bad_gains.yaml"
    bad.write_text(yaml.safe_dump(d))
    with caplog.at_level("CRITICAL"):
        code = lpv_controller_node.main(
            args=["n"] + args("lpv_controller.yaml", gains_file=str(bad))
        )
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
    probe.create_subscription(Odometry, "/lpv_sysid/state", states.append, qos_profile_sensor_data)
    refs = []
    probe.create_subscription(TwistStamped, "/lpv_sysid/velocity_reference", refs.append, 100)
    spin(list(g.values()), 4.0)
    ctl = g["ctl"].runtime
    assert ctl.supervisor.event is None and not g["sim"].runtime.handed_back
    sent = standin.find_publisher(g["ctl"], "actuator_command").standin_published
    assert sent == ctl.commands > 950  # 250 Hz for ~4 s (first tick waits for inputs)
    g["log"].destroy_node()
    bag = read_bag(str(tmp_path / "log" / "bag_0000"))
    assert len(bag["/lpv_sysid/actuator_command"]) == sent
    assert len(bag["/lpv_sysid/state"]) == 1000 and len(bag["/lpv_sysid/excitation"]) == 400
    # the vehicle follows v_d under the LPV law: forward speed error over the last 2 s
    v = np.array([messages.state_from_odometry(m).v_body[0] for m in states[-500:]])
    t_v = np.array([messages.stamp_ns_of(m) for m in states[-500:]])
    t_r = np.array([messages.stamp_ns_of(m) for m in refs])
    vd = np.interp(t_v, t_r, [messages.reference_from_twist(m)[1][0] for m in refs])
    rms = lambda a: np.sqrt(np.mean(a**2))  # noqa: E731
    assert np.ptp(vd) > 0.5 and np.corrcoef(v, vd)[0, 1] > 0.9
    assert rms(v - vd) < 0.5 * rms(vd)  # far better than not tracking at all


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
    assert max(messages.stamp_ns_of(c) for c in cmds) <= ev.t * 1e9
    if g["sim"] in nodes:
        assert g["sim"].runtime.handed_back
    return ev


def test_abort_on_stale_state(gains, signals2, tmp_path):
    def stop_sim(g, nodes):
        nodes.remove(g["sim"])  # the state stream stops (estimator/link failure)

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


def test_abort_on_reference_step(gains, signals2, tmp_path):
    """A step to 3 m/s (outside the box, and far faster than the design envelope of the
    gains) aborts on the envelope before any command follows it (issue 12 item 6); the
    box abort itself is covered in test_controller_safety.py with a slow ramp."""

    def big_reference(g, nodes):
        pub = g["probe"].create_publisher(TwistStamped, "/lpv_sysid/velocity_reference", 10)
        stamp = g["probe"].get_clock().now().nanoseconds + 5_000_000
        pub.publish(
            messages.twist_reference_msg(messages.MsgFactory.rclpy(), stamp, [3.0, 0.0, 0.0])
        )

    ev = _abort_case(gains, signals2, tmp_path, big_reference)
    assert ev.reason == "reference_envelope" and ev.detail.startswith("reference[0] changes at")


# ------------------------------------------------ issue 12: vehicle safety at node level
def _main_exit(caplog, **params):
    from lpv_sysid.nodes import lpv_controller_node

    with caplog.at_level("CRITICAL"):
        code = lpv_controller_node.main(args=["n"] + args("lpv_controller.yaml", **params))
    return code, caplog.records[-1].getMessage()


def test_node_refuses_inconsistent_esc_limits(gains, caplog):
    """u_esc_min:=0.9 u_esc_max:=0.1: before, the node started and clamped every motor to
    0.1 (per-parameter ranges only); now exit 2 naming the cross-field rule."""
    code, msg = _main_exit(caplog, gains_file=gains, u_esc_min=0.9, u_esc_max=0.1)
    assert code == 2 and "u_esc_min < u_esc_max" in msg


def test_node_refuses_gains_changed_after_certification(gains, tmp_path, caplog):
    d = yaml.safe_load(open(gains))
    d["vertices"][3]["K"] = (-np.array(d["vertices"][3]["K"])).tolist()
    bad = tmp_path / "gains.yaml"
    bad.write_text(yaml.safe_dump(d))
    (tmp_path / "gains.cert.npz").write_bytes(
        open(os.path.join(os.path.dirname(gains), "gains.cert.npz"), "rb").read()
    )
    code, msg = _main_exit(caplog, gains_file=str(bad))
    assert code == 2 and "certificate.gains_sha256" in msg and "does not match" in msg


def test_node_runs_the_values_of_its_yaml(gains, tmp_path):
    """config/lpv_controller.yaml set monitor_window_s, feedforward, ff_filter_tau and
    ff_jerk_tau, which the node did not declare, so it silently ran the defaults (issue 14
    item 1): the node's law now gets the file's values, as replay does."""
    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode

    text = open(os.path.join(CONFIG, "lpv_controller.yaml")).read()
    for key, value in (
        ("monitor_window_s", "12.0"),
        ("ff_filter_tau", "0.3"),
        ("ff_jerk_tau", "0.7"),
        ("feedforward", "false"),
    ):
        text = "\n".join(
            f"    {key}: {value}" if line.strip().startswith(f"{key}:") else line
            for line in text.splitlines()
        )
    f = tmp_path / "ctl.yaml"
    f.write_text(text)
    rclpy.init()
    node = LpvControllerNode(
        cli_args=["--ros-args", "--params-file", str(f), "-p", f"gains_file:={gains}"]
    )
    law = node.runtime.law
    assert (law.window, law.tau, law.tau_j, law.cfg.feedforward) == (12.0, 0.3, 0.7, False)
    d = node.describe_parameter("monitor_window_s")
    assert d.floating_point_range[0].to_value == 1e4 and "window" in d.description


def _exc_outputs(probe):
    refs, exc = [], []
    probe.create_subscription(TwistStamped, "/lpv_sysid/velocity_reference", refs.append, 100)
    probe.create_subscription(JointState, "/lpv_sysid/excitation", exc.append, 100)
    return refs, exc


def _ue(msgs):
    return np.array([messages.excitation_from_joint_state(m)[1] for m in msgs])


def _playing_excitation(signals2):
    """A phase-2 excitation node 1.5 s into its signal (ramp 1 s), a probe and its
    excitation messages."""
    from lpv_sysid.nodes.excitation_node import ExcitationNode

    rclpy.init()
    exc = ExcitationNode(
        cli_args=args(
            "excitation_node.yaml",
            signals_file=signals2,
            mode="phase2",
            ramp_s=1.0,
            auto_start=True,
        )
    )
    probe = rclpy.create_node("probe")
    _, out = _exc_outputs(probe)
    spin([exc, probe], 1.5)
    return exc, probe, out


def test_controller_abort_fades_the_excitation_within_one_ramp(gains, signals2, tmp_path):
    """Before, a controller abort left the excitation node playing at full amplitude."""
    g = graph(gains, signals2, tmp_path)
    refs, exc = _exc_outputs(g["probe"])
    nodes = list(g.values())
    spin(nodes, 1.5)
    assert np.abs(_ue(exc[-20:])).max() > 0.1  # playing (ramp 1 s done)
    assert call(g["probe"], nodes, "/lpv_sysid/lpv_controller/abort").success
    t_abort = g["ctl"].runtime.supervisor.event.t
    exc.clear()
    refs.clear()
    spin(nodes, 1.2)
    ts = np.array([messages.stamp_ns_of(m) * 1e-9 for m in exc])
    ue = np.abs(_ue(exc)).max(axis=1)
    assert g["exc"].runtime.aborted and "lpv_controller" in g["exc"].runtime.abort_reason
    assert np.all(ue[ts > t_abort + 1.0 + 0.011] == 0.0)  # faded within the 1 s ramp (+1 tick)
    assert ue[(ts > t_abort + 0.3) & (ts < t_abort + 0.5)].max() > 0  # a fade, not a cut
    v = np.array([[m.twist.linear.x, m.twist.linear.y, m.twist.linear.z] for m in refs])
    assert np.all(v[-5:] == 0.0)


@pytest.mark.parametrize(
    "sender, level, values, fades",
    [
        ("mavlink_bridge", "WARN", {"state": "HANDBACK"}, True),  # stale commands -> hand-back
        ("mavlink_bridge", "ERROR", {"state": "FAILED"}, True),
        ("campaign", "ERROR", {"phase": "aborting"}, True),
        ("lpv_controller", "ERROR", {"aborted": True}, True),
        # an ERROR that is no abort (the bridge refusing one message) and an unwatched node
        ("mavlink_bridge", "ERROR", {"state": "OFFBOARD_ACTIVE"}, False),
        ("sim_vehicle", "ERROR", {"aborted": True}, False),
    ],
)
def test_abort_status_of_a_watched_node_fades_the_excitation(
    signals2, sender, level, values, fades
):
    from diagnostic_msgs.msg import DiagnosticArray as DA

    exc, probe, out = _playing_excitation(signals2)
    pub = probe.create_publisher(DA, "/lpv_sysid/status", 10)
    f = messages.MsgFactory.rclpy()
    st = messages.diagnostic_status(f, level, f"/lpv_sysid/{sender}", "link lost", values)
    pub.publish(messages.diagnostic_array(f, standin.now_ns(), [st]))
    out.clear()
    spin([exc, probe], 1.2)
    assert exc.runtime.aborted == fades
    assert (np.abs(_ue(out[-5:])).max() == 0.0) == fades


def test_excitation_abort_survives_the_clock_going_back(signals2):
    """The node clock jumps back 5 s (sim time restarted): the excitation aborts and the
    fade completes within one ramp of the clock's time (before: TimeOrderError in the
    timer callback)."""
    exc, probe, out = _playing_excitation(signals2)
    real = exc.now_ns
    exc.now_ns = lambda: real() - 5_000_000_000
    out.clear()
    spin([exc, probe], 1.2)
    assert exc.runtime.aborted and exc.runtime.abort_reason == "node clock went back by 4.990 s"
    ue = np.abs(_ue(out)).max(axis=1)
    assert ue[:20].max() > 0 and np.all(ue[-15:] == 0.0)


def test_excitation_node_checks_the_signal_against_the_gains(gains, tmp_path, caplog):
    from lpv_sysid.nodes import excitation_node

    t = np.arange(0.0, 20.0, 0.02)
    cols = [0.8 * np.sin(2 * np.pi * 0.2 * t), 0 * t, 0 * t] + [3.0 * np.sin(9 * t)] * 4
    path = str(tmp_path / "loud.npz")
    save_npz(
        path, t, np.stack(cols, axis=1), ["u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r"]
    )
    with caplog.at_level("CRITICAL"):
        code = excitation_node.main(
            args=["n"]
            + args(
                "excitation_node.yaml",
                signals_file=path,
                mode="phase2",
                ramp_s=1.0,
                gains_file=gains,
            )
        )
    assert (
        code == 2
        and "ue_t peak 3 exceeds the design excitation peak 1" in caplog.records[-1].getMessage()
    )


def test_safety_abort_is_logged_by_the_node_logger(gains, signals2, tmp_path, caplog):
    """issue 11: the abort line went through Python logging of controller_runtime (no
    timestamp, never on /rosout); now the node's own logger says it."""
    g = graph(gains, signals2, tmp_path)
    nodes = list(g.values())
    spin(nodes, 1.0)
    with caplog.at_level("INFO"):
        call(g["probe"], nodes, "/lpv_sysid/lpv_controller/abort")
        spin(nodes, 0.1)
    lines = [r for r in caplog.records if r.getMessage().startswith("safety abort: external")]
    assert lines and {r.name for r in lines} == {g["ctl"].get_logger().name}
    assert not [r for r in caplog.records if r.name.startswith("lpv_sysid.nodes.")]


# ------------------------------------------------------- the tick's command builder, GC policy
@pytest.mark.parametrize("kind", ["rosbags", "rclpy"])
def test_command_builder_equals_io_messages(kind):
    """The tick's actuator_command equals io.messages.actuator_command_msg field by field (both
    factories: rosbags for replay, rclpy for the node), and a stamp beyond builtin_interfaces/
    Time is refused by io.messages' own check."""
    from lpv_sysid.flight.controller import CommandBuilder

    f = messages.MsgFactory.rosbags() if kind == "rosbags" else messages.MsgFactory.rclpy()
    build = CommandBuilder(f)
    u = np.array([0.51, -0.012, 0.034, 1e-3])
    for stamp in (0, 1_704_067_205_004_000_000, 999_999_999, -1_500_000_000):
        a, b = build(stamp, u), messages.actuator_command_msg(f, stamp, u)
        assert type(a) is type(b)
        assert (a.header.stamp.sec, a.header.stamp.nanosec, a.header.frame_id) == (
            b.header.stamp.sec,
            b.header.stamp.nanosec,
            b.header.frame_id,
        )
        assert list(a.name) == list(b.name) == list(INPUT_NAMES)
        for field in ("position", "velocity", "effort"):
            assert type(getattr(a, field)) is type(getattr(b, field))
            assert list(getattr(a, field)) == list(getattr(b, field))
        assert messages.actuator_command_from_joint_state(a)[1].tolist() == u.tolist()
    with pytest.raises(messages.MessageError, match="int32"):
        build(2**31 * 10**9, u)


def test_node_freezes_the_loaded_heap(gains):
    """settle_gc after loading: the objects alive then are in the permanent generation (the
    full collections during flight no longer walk them)."""
    import gc

    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode

    gc.unfreeze()
    assert gc.get_freeze_count() == 0
    rclpy.init()
    node = LpvControllerNode(cli_args=args("lpv_controller.yaml", gains_file=gains))
    try:
        assert gc.get_freeze_count() > 10_000
        assert gc.get_count()[2] == 0  # a full collection just ran
    finally:
        node.destroy_node()
        gc.unfreeze()


def test_lockstep_controller_answers_every_state_sample_before_start(gains):
    """lockstep (sim.launch.py): before start the controller answers each state sample of
    the lock-stepped sim_vehicle on lockstep_ack (stamped with it, no command), so the
    simulation waits for it from its first sample on -- not only from its first command
    (test_lockstep_graph.py: the stall after start that this closes)."""
    from rosgraph_msgs.msg import Clock

    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode
    from lpv_sysid.nodes.sim_vehicle_node import SimVehicleNode

    rclpy.init()
    sim = SimVehicleNode(cli_args=args("sim_vehicle.yaml", mode="lpv", lockstep=True))
    ctl = LpvControllerNode(
        cli_args=args("lpv_controller.yaml", gains_file=gains, tick_source="state", lockstep=True)
    )
    assert dict(ctl.get_topic_names_and_types())["/lpv_sysid/lockstep_ack"] == [
        "rosgraph_msgs/msg/Clock"
    ]
    probe = rclpy.create_node("probe")
    states, acks, cmds = [], [], []
    probe.create_subscription(Odometry, "/lpv_sysid/state", states.append, qos_profile_sensor_data)
    probe.create_subscription(Clock, "/lpv_sysid/lockstep_ack", acks.append, 100)
    probe.create_subscription(JointState, "/lpv_sysid/actuator_command", cmds.append, 10)
    spin([sim, ctl, probe], 0.5)
    assert sim.runtime.engaged and not ctl.runtime.supervisor.armed and cmds == []
    sent = sorted({messages.stamp_ns_of(m) for m in states})
    answered = [messages.clock_ns_of(m) for m in acks]
    assert len(sent) > 50 and answered == sent[: len(answered)] and len(sent) - len(answered) <= 1
    assert sim.runtime.lockstep_timeouts == 0


def test_lockstep_needs_tick_source_state(gains):
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.flight.controller import ControllerSettings

    with pytest.raises(ConfigError, match="lockstep needs tick_source state"):
        ControllerSettings(gains_file=gains, lockstep=True)
