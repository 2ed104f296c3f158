"""Node shells through the rclpy stand-in: parameters, topics, QoS, services, data flow."""

import os

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError
import rclpy
import rclpy._standin as standin
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy._standin import call_trigger as call
from rclpy._standin import spin_nodes as spin
from rclpy.parameter import Parameter
from rclpy.qos import QoSReliabilityPolicy
from sensor_msgs.msg import JointState

from lpv_sysid.io import messages
from lpv_sysid.io.bag import read_bag
from lpv_sysid.signals.excitation import ExcitationCore
from lpv_sysid.signals.store import save_npz

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "config")
NS = "lpv_sysid"


@pytest.fixture(autouse=True)
def fresh():
    standin.reset()
    yield
    rclpy.try_shutdown()


@pytest.fixture
def signals1(tmp_path):
    """Phase-1 table: 0.5 Hz sine on v_ref (FRD) of amplitude 0.5 m/s, 20 s at 50 Hz."""
    t = np.arange(0.0, 20.0, 0.02)
    s = 0.5 * np.sin(2 * np.pi * 0.5 * t)
    path = str(tmp_path / "sig1.npz")
    save_npz(
        path, t, np.stack([0 * t, s, 0 * t, 0.1 * s], axis=1), ["u_ref", "v_ref", "w_ref", "r_ref"]
    )
    return path


def ros_args(*pairs, params_file=None):
    args = ["node", "--ros-args"]
    if params_file:
        args += ["--params-file", os.path.join(CONFIG, params_file)]
    for k, v in pairs:
        args += ["-p", f"{k}:={v}"]
    return args


def collect(node, msg_type, topic, qos=100):
    out = []
    node.create_subscription(msg_type, topic, out.append, qos)
    return out


# ------------------------------------------------------------------ excitation_node
def test_excitation_parameters_topics_qos(signals1):
    from lpv_sysid.nodes.excitation_node import ExcitationNode

    rclpy.init(args=ros_args(("signals_file", signals1), params_file="excitation_node.yaml"))
    node = ExcitationNode(namespace=NS)
    # parameters from config/excitation_node.yaml, typed and described
    assert node.get_parameter("rate_hz").value == 100.0
    assert node.get_parameter("ramp_s").value == 2.0
    d = node.describe_parameter("rate_hz")
    assert d.type == Parameter.Type.DOUBLE.value and d.description
    assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (
        1.0,
        1000.0,
    )
    res = node.set_parameters([Parameter("rate_hz", value=5000.0)])
    assert not res[0].successful and "read-only" in res[0].reason  # applied at start only
    res = node.set_parameters([Parameter("status_rate_hz", value=500.0)])
    assert not res[0].successful and "out of range" in res[0].reason
    assert dict(node.get_topic_names_and_types()) == {
        "/lpv_sysid/velocity_reference": ["geometry_msgs/msg/TwistStamped"],
        "/lpv_sysid/excitation": ["sensor_msgs/msg/JointState"],
        "/lpv_sysid/status": ["diagnostic_msgs/msg/DiagnosticArray"],
        "/diagnostics": ["diagnostic_msgs/msg/DiagnosticArray"],
    }
    for topic in ("velocity_reference", "excitation", "status"):
        pub = standin.find_publisher(node, topic)
        assert pub.qos_profile.reliability == QoSReliabilityPolicy.RELIABLE
    assert sorted(n for n, _ in node.get_service_names_and_types()) == [
        "/lpv_sysid/excitation/abort",
        "/lpv_sysid/excitation/start",
    ]


def test_excitation_phase1_plays_core_in_flu(signals1):
    from lpv_sysid.nodes.excitation_node import ExcitationNode

    rclpy.init(
        args=ros_args(
            ("signals_file", signals1),
            ("vertex_frd", "[2.0, 1.0, -0.5]"),
            ("ramp_s", 1.0),
            params_file="excitation_node.yaml",
        )
    )
    node = ExcitationNode(namespace=NS)
    probe = rclpy.create_node("probe")
    refs = collect(probe, TwistStamped, "/lpv_sysid/velocity_reference")
    spin([node, probe], 0.2)
    # before start: the vertex (trim) reference, FRD (2, 1, -0.5) -> FLU (2, -1, 0.5)
    v = refs[-1].twist.linear
    assert (v.x, v.y, v.z) == (2.0, -1.0, 0.5) and len(refs) == 20
    resp = call(probe, [node], "/lpv_sysid/excitation/start")
    assert resp.success and "phase1" in resp.message
    t_start = node.runtime.core.start_time
    refs.clear()
    spin([node, probe], 3.0)
    # oracle: an independent core with the same table and start time, converted FRD -> FLU
    from lpv_sysid.signals.store import load_npz

    t, u, names = load_npz(signals1)
    oracle = ExcitationCore.phase1(
        t, u, names, start_time=t_start, vertex_velocity=[2.0, 1.0, -0.5], ramp=1.0
    )
    ts = np.array([messages.stamp_ns_of(m) * 1e-9 for m in refs])
    v_exp, r_exp, _ = oracle.evaluate(ts)
    got = np.array([[m.twist.linear.x, m.twist.linear.y, m.twist.linear.z] for m in refs])
    np.testing.assert_allclose(got, v_exp * [1, -1, -1], atol=1e-12)
    np.testing.assert_allclose([m.twist.angular.z for m in refs], -r_exp, atol=1e-12)
    assert np.ptp(got[:, 1]) > 0.5  # the multisine is really there
    ns = np.array([messages.stamp_ns_of(m) for m in refs])
    assert np.all(np.diff(ns) == 10_000_000)  # 100 Hz, no accumulated drift


def test_excitation_abort_fades_to_zero(signals1):
    from lpv_sysid.nodes.excitation_node import ExcitationNode

    rclpy.init(
        args=ros_args(
            ("signals_file", signals1),
            ("mode", "phase1"),
            ("vertex_frd", "[1.0, 0.0, 0.0]"),
            ("ramp_s", 0.5),
            ("auto_start", True),
            params_file="excitation_node.yaml",
        )
    )
    node = ExcitationNode(namespace=NS)
    probe = rclpy.create_node("probe")
    refs = collect(probe, TwistStamped, "/lpv_sysid/velocity_reference")
    status = collect(probe, DiagnosticArray, "/lpv_sysid/status")
    spin([node, probe], 1.0)
    assert call(probe, [node], "/lpv_sysid/excitation/abort").success
    refs.clear()
    spin([node, probe], 1.0)
    last = refs[-1].twist.linear
    assert (last.x, last.y, last.z) == (0.0, 0.0, 0.0)
    _, st = messages.status_from_diagnostic_array(status[-1])
    assert st[0].level == 1 and st[0].values["phase"] == "aborted"
    assert not call(probe, [node], "/lpv_sysid/excitation/start").success


def test_excitation_bad_parameters(tmp_path, signals1, caplog):
    from lpv_sysid.nodes import excitation_node

    bad = tmp_path / "bad.yaml"
    bad.write_text("/**/excitation:\n  ros__parameters:\n    rate_hz: 100\n")
    rclpy.init(args=["n", "--ros-args", "--params-file", str(bad)])
    # a mistyped value is one named error (shell.declare), not rclpy's exception
    with pytest.raises(ConfigError, match="parameter 'rate_hz': .*DOUBLE"):
        excitation_node.ExcitationNode(namespace=NS)
    rclpy.shutdown()
    standin.reset()
    # an empty signals_file: main() exits 2 with one FATAL line naming the parameter
    with caplog.at_level("CRITICAL"):
        assert excitation_node.main(args=["n"]) == 2
    assert "signals_file" in caplog.records[-1].getMessage()


# ------------------------------------------------------------------ sim_vehicle_node
def test_sim_vehicle_baseline_tracks_reference():
    from lpv_sysid.nodes.sim_vehicle_node import SimVehicleNode

    rclpy.init(args=ros_args(params_file="sim_vehicle.yaml"))
    node = SimVehicleNode(namespace=NS)
    for topic in ("state", "imu", "rotor_speeds"):
        assert (
            standin.find_publisher(node, topic).qos_profile.reliability
            == QoSReliabilityPolicy.BEST_EFFORT
        )
    probe = rclpy.create_node("probe")
    from rclpy.qos import qos_profile_sensor_data

    states = collect(probe, Odometry, "/lpv_sysid/state", qos_profile_sensor_data)
    rotors = collect(probe, JointState, "/lpv_sysid/rotor_speeds", qos_profile_sensor_data)
    pub = probe.create_publisher(TwistStamped, "/lpv_sysid/velocity_reference", 10)
    f = messages.MsgFactory.rclpy()
    probe.create_timer(
        0.02,
        lambda: pub.publish(
            messages.twist_reference_msg(
                f, probe.get_clock().now().nanoseconds, [1.0, 0.0, 0.0], 0.0
            )
        ),
    )
    spin([node, probe], 4.0)
    # 250 Hz state and 100 Hz rotor speeds over 4 s (probe's KEEP_LAST depth 5 never overflows
    # because the executor runs each callback as soon as its message is queued)
    assert len(states) == 1000 and len(rotors) == 400
    s = messages.state_from_odometry(states[-1])
    assert abs(s.v_body[0] - 1.0) < 0.2 and abs(node.runtime.vehicle.x[6] - 1.0) < 0.1
    assert np.all(np.diff([m.header.stamp.nanosec for m in states[:10]]) == 4_000_000)


def test_sim_vehicle_keeps_real_time_through_a_late_tick_and_slips_when_overloaded():
    """A 50 ms late timer (measured under real Jazzy on 2 loaded cores: gaps to 66 ms) no
    longer loses physics time or leaves a gap in the stamps: the tick catches up in fixed
    steps, stamps stay 4 ms apart. Beyond max_catch_up_s the simulation slips instead."""
    from lpv_sysid.nodes.sim_vehicle_node import SimVehicleNode

    rclpy.init(args=ros_args(params_file="sim_vehicle.yaml"))
    node = SimVehicleNode(namespace=NS)
    probe = rclpy.create_node("probe")
    from rclpy.qos import QoSProfile
    from rclpy.qos import QoSReliabilityPolicy as Rel

    states = collect(
        probe, Odometry, "/lpv_sysid/state", QoSProfile(depth=1000, reliability=Rel.BEST_EFFORT)
    )
    ctx = rclpy.get_default_context()
    spin([node, probe], 0.2)
    k0, n0 = node.runtime.k, len(states)
    ctx._standin_now_ns += 50_000_000  # the executor was busy for 50 ms
    node.on_tick()
    assert node.runtime.k - k0 == 25  # 500 Hz physics: 25 steps made up
    spin([node, probe], 0.0)
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in states]
    assert len(states) - n0 == 12 or len(states) - n0 == 13
    assert set(np.diff(stamps)) == {4_000_000}  # no gap in the physics stamps
    assert node.runtime.slip_ns == 0
    k1 = node.runtime.k
    ctx._standin_now_ns += 1_000_000_000  # 1 s stall: more than 0.1 s catch-up
    node.on_tick()
    assert node.runtime.slip_ns == pytest.approx(0.9e9, abs=2.1e6)  # physics lost 0.9 s ...
    assert node.runtime.k - k1 == 50  # ... and made up 0.1 s
    assert (
        0 <= ctx._standin_now_ns - node.runtime.physics_stamp_ns() < node.runtime.dt_ns
    )  # stamps: the clock


# ------------------------------------------------------------------ data_logger_node
def test_logger_records_excitation_and_closes(tmp_path, signals1):
    from lpv_sysid.nodes.data_logger_node import DataLoggerNode
    from lpv_sysid.nodes.excitation_node import ExcitationNode

    out = tmp_path / "log"
    rclpy.init(args=ros_args())
    # each node its own parameters (a key of the other node would be refused as unknown)
    exc = ExcitationNode(
        namespace=NS,
        cli_args=ros_args(
            ("signals_file", signals1), ("auto_start", True), params_file="excitation_node.yaml"
        )[1:],
    )
    log = DataLoggerNode(
        namespace=NS,
        cli_args=ros_args(
            ("out_dir", str(out)),
            ("split_duration_s", 1.0),
            ("config_files", f"['{CONFIG}/excitation_node.yaml']"),
            params_file="data_logger.yaml",
        )[1:],
    )
    spin([exc, log], 2.5)
    sent = standin.find_publisher(exc, "excitation").standin_published
    standin.find_subscription(log, "excitation").standin_lose(2)  # middleware-reported loss
    log.destroy_node()
    meta = yaml.safe_load((out / "experiment.yaml").read_text())
    assert meta["closed_cleanly"] and [b["path"] for b in meta["bags"]] == [
        "bag_0000",
        "bag_0001",
        "bag_0002",
    ]
    assert meta["topics"]["/lpv_sysid/excitation"]["dropped"] == 2
    assert (meta["clock"]["kind"], meta["clock"]["offset_ns"]) == ("utc", 0)
    assert "excitation_node.yaml" in next(iter(meta["config_files"]))
    got = []
    for b in meta["bags"]:
        got += read_bag(str(out / b["path"]), topics=["/lpv_sysid/excitation"]).get(
            "/lpv_sysid/excitation", []
        )
    assert len(got) == sent == 250
    assert meta["topics"]["/lpv_sysid/excitation"]["rate_hz"] == pytest.approx(100.0)
    assert list(got[0][1].name) == ["ue_t", "ue_a", "ue_e", "ue_r"]


def test_logger_main_closes_bag_on_shutdown(tmp_path):
    from lpv_sysid.nodes import data_logger_node

    out = tmp_path / "log2"
    standin.shutdown_at(1.5)  # like SIGTERM: rclpy shuts the context down, spin returns
    assert (
        data_logger_node.main(args=ros_args(("out_dir", str(out)), ("topics", "['status']"))) == 0
    )
    meta = yaml.safe_load((out / "experiment.yaml").read_text())
    assert meta["closed_cleanly"] is True
    # its own 1 Hz status is recorded: t = 0 (the first, at start) and 1.0 s (the 1.5 s
    # shutdown comes first)
    bag = read_bag(str(out / "bag_0000"))
    assert len(bag["/lpv_sysid/status"]) == meta["topics"]["/lpv_sysid/status"]["count"] == 2


def stepping_probe(veh):
    """``(probe node, t0 [ns])``: the probe's 4 ms timer steps the simulated PX4 ``veh`` on the
    node clock from ``t0``."""
    probe = rclpy.create_node("probe")
    t0 = probe.get_clock().now().nanoseconds
    probe.create_timer(0.004, lambda: veh.step((probe.get_clock().now().nanoseconds - t0) * 1e-9))
    return probe, t0


# ------------------------------------------------------------------ mavlink_bridge_node
def _free_udp_port():
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_bridge_publishes_telemetry_of_mavlink_vehicle():
    """Bridge against the simulated PX4 over UDP 127.0.0.1, lock-stepped to the sim clock."""
    from lpv_sysid.nodes.mavlink_bridge_node import MavlinkBridgeNode
    from lpv_sysid.sim.px4_vehicle import SimVehicle, SimVehicleConfig

    port = _free_udp_port()
    rclpy.init(
        args=ros_args(
            ("link.url", f"udpin:127.0.0.1:{port}"), params_file="mavlink_bridge_node.yaml"
        )
    )
    node = MavlinkBridgeNode(namespace=NS)
    veh = SimVehicle(SimVehicleConfig(url=f"udpout:127.0.0.1:{port}"))
    veh.open()
    try:
        probe, t0 = stepping_probe(veh)
        from rclpy.qos import qos_profile_sensor_data

        states = collect(probe, Odometry, "/lpv_sysid/state", qos_profile_sensor_data)
        status = collect(probe, DiagnosticArray, "/lpv_sysid/status")
        spin([node, probe], 2.0)
        # phase-1 path: start offboard, stream velocity references (FLU forward 1 m/s)
        f = messages.MsgFactory.rclpy()
        pub = probe.create_publisher(TwistStamped, "/lpv_sysid/velocity_reference", 10)
        probe.create_timer(
            0.02,
            lambda: pub.publish(
                messages.twist_reference_msg(
                    f, probe.get_clock().now().nanoseconds, [1.0, 0.0, 0.0]
                )
            ),
        )
        assert call(probe, [node], "/lpv_sysid/mavlink_bridge/start").success
        spin([node, probe], 3.0)
        offboard_state = node.core.state.value
        received = veh.setpoints_received
        mode = veh.mode
    finally:
        veh.close()
        node.destroy_node()
    # the PX4 simulator received the setpoints and switched to OFFBOARD after prestreaming
    assert offboard_state == "OFFBOARD_ACTIVE" and received > 50
    from lpv_sysid.mavlink import px4

    assert mode == px4.OFFBOARD
    assert len(states) > 10
    s = states[-1]
    # vehicle on the ground, heading north: NED yaw 0 is ENU yaw +90 deg
    q = s.pose.pose.orientation
    np.testing.assert_allclose([q.x, q.y, q.z, q.w], [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-3)
    assert s.header.frame_id == "odom" and s.child_frame_id == "base_link"
    _, st = messages.status_from_diagnostic_array(status[-1])
    assert st[0].values["link_up"] == "True"


def test_logger_node_sigterm_closes_bag(tmp_path):
    """data_logger_node main() in a subprocess killed by SIGTERM: rclpy's handler shuts the
    context down, spin returns, destroy_node closes the bag -- it opens afterwards."""
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "log"
    code = (
        f"import sys; sys.path[:0] = [{ROOT!r}, {os.path.join(ROOT, 'test', 'support')!r}]\n"
        "from lpv_sysid.nodes.data_logger_node import main\n"
        f"sys.exit(main(args=['n', '--ros-args', '-p', 'out_dir:={out}', "
        "'-p', 'topics:=[status]', '-p', 'status_rate_hz:=10.0']))\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code])
    try:
        for _ in range(300):
            if (out / "bag_0000").exists():
                break
            time.sleep(0.05)
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    meta = yaml.safe_load((out / "experiment.yaml").read_text())
    assert meta["closed_cleanly"] is True
    bag = read_bag(str(out / "bag_0000"))
    assert len(bag["/lpv_sysid/status"]) == meta["topics"]["/lpv_sysid/status"]["count"] > 0


def test_logger_writes_the_bridges_vehicle_record(tmp_path):
    """The bridge's vehicle record from the simulated PX4 (its parameters, AUTOPILOT_VERSION,
    battery, home) reaches the data logger's ``experiment.yaml`` ``vehicle`` -- the logger
    started 1 s after the record went out (transient local) -- in the mapping ``fly`` writes
    (VehicleRecord.summary: the same keys), with PX4's boot on the bag clock: the probe's
    clock when the simulation's time 0 was."""
    from lpv_sysid.mavlink.telemetry import VehicleRecord
    from lpv_sysid.nodes.data_logger_node import DataLoggerNode
    from lpv_sysid.nodes import shell
    from lpv_sysid.nodes.mavlink_bridge_node import MavlinkBridgeNode
    from lpv_sysid.sim.px4_vehicle import SimVehicle, SimVehicleConfig
    from lpv_sysid.sim.px4_vehicle.config import DEFAULT_PARAMS
    from lpv_sysid.sim.px4_vehicle.telemetry import HOME_LAT, HOME_LON
    from std_msgs.msg import String

    port = _free_udp_port()
    out = tmp_path / "log"
    rclpy.init(args=ros_args())
    node = MavlinkBridgeNode(
        namespace=NS,
        cli_args=ros_args(
            ("link.url", f"udpin:127.0.0.1:{port}"), params_file="mavlink_bridge_node.yaml"
        )[1:],
    )
    veh = SimVehicle(
        SimVehicleConfig(
            url=f"udpout:127.0.0.1:{port}",
            params={"MPC_XY_VEL_MAX": 7.5},
            battery_voltage=15.2,
        )
    )
    veh.open()
    try:
        probe, t0 = stepping_probe(veh)
        records = collect(probe, String, "/lpv_sysid/vehicle_record", shell.QOS_VEHICLE_RECORD)
        spin([node, probe], 3.0)
        n_before = len(records)
        log = DataLoggerNode(
            namespace=NS,
            cli_args=ros_args(("out_dir", str(out)), params_file="data_logger.yaml")[1:],
        )
        spin([node, probe, log], 2.0)
        log.destroy_node()
    finally:
        veh.close()
        node.destroy_node()
    # published on material changes only: a handful, not at the 250 Hz poll rate
    assert 1 <= n_before <= 6, n_before
    meta = yaml.safe_load((out / "experiment.yaml").read_text())
    v = meta["vehicle"]
    assert set(v) == set(VehicleRecord().summary())
    assert v["kind"] == "SIMULATED"
    assert v["firmware"]["flight_sw_version"] == "v1.16.0"
    want = {k: d for k, (d, _) in DEFAULT_PARAMS.items()}
    want["MPC_XY_VEL_MAX"] = 7.5
    assert v["px4_parameters"] == pytest.approx(want)
    assert v["battery"]["start"]["voltage_v"] == pytest.approx(15.2, abs=1e-3)
    assert v["site"]["latitude_deg"] == pytest.approx(HOME_LAT, abs=1e-7)
    assert v["site"]["longitude_deg"] == pytest.approx(HOME_LON, abs=1e-7)
    # PX4 booted at the probe's t0; the estimate is late by the smallest latency (here the
    # 4 ms poll period at most) + 1 ms of time_boot_ms truncation, never early
    boot = v["px4_clock"]["boot_ns_min"]
    assert 0 <= boot - t0 <= 5_000_000, boot - t0
    assert v["px4_clock"]["boot_samples"] > 100
    assert meta["clock"] == {**meta["clock"], "kind": "utc", "offset_ns": 0}
    assert "vehicle_record_clock" not in meta["clock"]
