"""Phase 2 on PX4 through the node graph (issue 21 items 2 and 4), rclpy stand-in: the nodes of
``phase2.launch.py design:=rate_plant`` -- excitation (phase 2), lpv_controller with
config/lpv_controller_px4.yaml and the rate-plant gains, mavlink_bridge with command
rate_setpoint, data_logger -- against the PX4-faithful simulated vehicle (airborne in HOLD),
on the stand-in's simulated clock (the vehicle is stepped by a timer; MAVLink still travels
over 127.0.0.1 UDP). Oracles: the vehicle's own record of the setpoints it received, the
configured stream and node rates, PX4's mode.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import rclpy
import rclpy._standin as standin
from rclpy._standin import spin_nodes as spin
from test_chain_px4 import _vehicle, design  # noqa: F401  (module fixture)

from lpv_sysid.io import messages
from lpv_sysid.io.bag import read_bag, topic_info

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "config")
NAMES = ("thrust", "p_sp", "q_sp", "r_sp")


@pytest.fixture(autouse=True)
def fresh():
    standin.reset()
    yield
    rclpy.try_shutdown()


def args(params_file, **params):
    a = ["--ros-args", "--params-file", os.path.join(CONFIG, params_file)]
    for k, v in params.items():
        a += ["-p", f"{k}:={v}"]
    return a


def test_rate_plant_graph_flies_phase2_on_px4_and_records_every_topic(design, tmp_path):  # noqa: F811
    from lpv_sysid.nodes.data_logger_node import DataLoggerNode
    from lpv_sysid.nodes.excitation_node import ExcitationNode
    from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode
    from lpv_sysid.nodes.mavlink_bridge_node import MavlinkBridgeNode

    veh, _ = _vehicle(tmp_path, airborne=True)
    port = veh.config.url.rsplit(":", 1)[-1]
    gains, signals = str(design / "gains.yaml"), str(design / "signals" / "signals.npz")
    rclpy.init()
    try:
        stepper = rclpy.create_node("px4")
        clock = stepper.get_clock()
        t0 = clock.now().nanoseconds * 1e-9  # the vehicle's time starts at 0
        stepper.create_timer(0.004, lambda: veh.step(clock.now().nanoseconds * 1e-9 - t0))
        nodes = {
            "exc": ExcitationNode(
                cli_args=args(
                    "excitation_node.yaml",
                    signals_file=signals,
                    gains_file=gains,
                    mode="phase2",
                    start_delay_s=2.5,
                    duration_s=5.0,
                    auto_start=True,
                )
            ),
            "ctl": LpvControllerNode(
                cli_args=args(
                    "lpv_controller_px4.yaml",
                    gains_file=gains,
                    signals_file=signals,
                    auto_start=True,
                )
            ),
            "bridge": MavlinkBridgeNode(
                cli_args=args(
                    "mavlink_bridge_node.yaml",
                    **{
                        "link.url": f"udpin:127.0.0.1:{port}",
                        "command": "rate_setpoint",
                        "auto_start": True,
                    },
                )
            ),
            "log": DataLoggerNode(
                cli_args=args("data_logger.yaml", out_dir=str(tmp_path / "log"))
            ),
        }
        all_nodes = [stepper, *nodes.values()]
        spin(all_nodes, 8.5)  # start, OFFBOARD (~2.2 s), 2.5 s delay, 5 s signal, margin
        ctl = nodes["ctl"].runtime
        assert ctl.design == "rate_plant" and ctl.supervisor.event is None
        assert nodes["exc"].runtime.core.progress.phase == "done"
        modes = [m for _, m, _ in veh.mode_log]
        assert modes == ["OFFBOARD"], modes
        # hand-back as today: the bridge's abort -> HOLD confirmed
        nodes["bridge"].runtime.abort(clock.now().nanoseconds * 1e-9)
        spin(all_nodes, 1.5)
        assert veh.mode.name == "HOLD" and nodes["bridge"].runtime.core.state.value == "DONE"
        nodes["log"].destroy_node()
    finally:
        veh.close()
    bag = tmp_path / "log" / "bag_0000"
    info = {k.rsplit("/", 1)[-1]: v for k, v in topic_info(str(bag)).items()}
    print({k: (v.count, round(v.rate_hz, 1)) for k, v in info.items()})
    expected = {  # config/mavlink_bridge_node.yaml streams, motor outputs, node rates
        "state": 100.0 + 50.0,  # one sample per ATTITUDE_QUATERNION and LOCAL_POSITION_NED
        "imu": 100.0,
        "rotor_speeds": 50.0,  # estimated from ACTUATOR_OUTPUT_STATUS (no ESC telemetry)
        "velocity_reference": 100.0,  # excitation rate_hz
        "excitation": 100.0,
    }
    for topic, hz in expected.items():
        assert info[topic].rate_hz == pytest.approx(hz, rel=0.05), (topic, info[topic])
    # 2 Hz per node (4 nodes) plus the events; no rejection of each velocity_reference
    assert 4 * 2 * 8 < info["status"].count < 200
    got = read_bag(str(bag))
    rotor = [m for _, m in got["/lpv_sysid/rotor_speeds"]]
    assert {messages.rotor_source_of(m) for m in rotor} == {"estimated"}
    # the setpoints sent and PX4's echo (50 Hz while it tracks them in OFFBOARD)
    sent = {
        messages.stamp_ns_of(m): messages.channels_from_joint_state(m, NAMES)[1]
        for _, m in got["/lpv_sysid/actuator_command"]
    }
    assert len(sent) > 100 * 7
    echo = got["/lpv_sysid/rate_setpoint"]
    t_echo = np.array([t for t, _ in echo]) * 1e-9
    assert (len(t_echo) - 1) / (t_echo[-1] - t_echo[0]) == pytest.approx(50.0, rel=0.05)
    vals = np.array([messages.channels_from_joint_state(m, NAMES)[1] for _, m in echo])
    table = np.array(list(sent.values()))
    clipped = np.column_stack([np.clip(table[:, 0], 0.05, 0.95), np.clip(table[:, 1:], -2, 2)])
    for row in vals[5::20]:  # every echoed setpoint is one the controller sent
        assert np.min(np.abs(clipped - row).max(axis=1)) < 1e-5
    # the excitation was flown (not zeros) and its stamps answer the state stamps
    ue = np.array(
        [messages.excitation_from_joint_state(m)[1] for _, m in got["/lpv_sysid/excitation"]]
    )
    assert np.abs(ue).max() > 0.05
    # the loop latency from the logger's bag (here on the stand-in's simulated clock: the
    # logger receives at the publishing instant; under real rclpy the DDS hop adds to it)
    from lpv_sysid.flight.phase2 import latency_from_bag

    lat = latency_from_bag(bag)
    assert lat["commands"] == len(got["/lpv_sysid/actuator_command"]) and lat["max"] >= 0.0


@pytest.mark.parametrize("case", ["K_negated", "sidecar_missing", "v_d_x3", "kappa_10"])
def test_controller_node_refuses_the_tampers_fly_phase2_refuses(design, tmp_path, caplog, case):  # noqa: F811
    """``lpv_controller_node`` (the shell, stand-in rclpy) exits 2 with the words of the
    runtime for the tamper cases of test_phase2_one_path (the same ones ``fly phase2`` and the
    chain refuse with those words)."""
    from test_phase2_one_path import _node_runtime, _tampered

    from lpv_sysid.errors import ConfigError
    from lpv_sysid.nodes import lpv_controller_node

    gains, signals, kappa = _tampered(design, tmp_path, case)
    with pytest.raises(ConfigError) as rt:
        _node_runtime(gains, signals, kappa)
    with caplog.at_level("CRITICAL"):
        code = lpv_controller_node.main(
            args=["n"]
            + args(
                "lpv_controller_px4.yaml",
                gains_file=str(gains),
                signals_file=str(signals / "signals.npz"),
                excitation_gain=kappa,
            )
        )
    assert code == 2
    assert str(rt.value) in caplog.records[-1].getMessage()
