"""nodes/shell.ShellNode (the base of every node shell) through the rclpy stand-in."""

import logging

import numpy as np
import pytest
import rclpy
import rclpy._standin as standin
from rclpy.parameter import Parameter

from lpv_sysid.io import messages
from lpv_sysid.nodes import shell
from lpv_sysid.nodes.data_logger_node import DataLoggerNode
from lpv_sysid.nodes.excitation_node import ExcitationNode
from lpv_sysid.nodes.lpv_controller_node import LpvControllerNode
from lpv_sysid.nodes.mavlink_bridge_node import MavlinkBridgeNode
from lpv_sysid.nodes.sim_vehicle_node import SimVehicleNode

TABLE = [
    ("rate_hz", 50.0, shell.double("a rate [Hz]", 1.0, 100.0)),
    ("label", "x", shell.typed(Parameter.Type.STRING, "a label")),
    ("names", Parameter.Type.STRING_ARRAY, shell.typed(Parameter.Type.STRING_ARRAY, "a list")),
]


class _Probe(shell.ShellNode):
    def __init__(self, **kwargs):
        super().__init__("probe", TABLE, **kwargs)


@pytest.fixture(autouse=True)
def fresh():
    standin.reset()
    yield
    rclpy.try_shutdown()


def test_every_node_shell_derives_from_shellnode():
    for cls in (
        ExcitationNode,
        LpvControllerNode,
        MavlinkBridgeNode,
        DataLoggerNode,
        SimVehicleNode,
    ):
        assert issubclass(cls, shell.ShellNode)


def test_namespace_parameters_and_clock():
    rclpy.init(args=["n", "--ros-args", "-p", "rate_hz:=20.0"])
    node = _Probe()
    assert node.get_fully_qualified_name() == "/lpv_sysid/probe"
    # overridden, default, and unset list parameter (declared without default -> [])
    assert node.params == {"rate_hz": 20.0, "label": "x", "names": []}
    ns = standin.now_ns()
    assert node.now_ns() == ns and node.now() == pytest.approx(ns * 1e-9, abs=1e-12)
    other = _Probe(namespace="elsewhere")
    assert other.get_fully_qualified_name() == "/elsewhere/probe"
    node.destroy_node()
    other.destroy_node()


def test_parse_input_passes_good_and_drops_bad_messages(caplog):
    rclpy.init(args=["n"])
    node = _Probe()
    f = messages.MsgFactory.rclpy()
    good = messages.actuator_command_msg(f, 1_500_000_000, [0.5, 0.01, -0.02, 0.1])
    t, u = node.parse_input("actuator_command", messages.actuator_command_from_joint_state, good)
    assert t == pytest.approx(1.5) and np.allclose(u, [0.5, 0.01, -0.02, 0.1])
    bad = messages.joint_state(f, 1_500_000_000, ["ut", "ua", "ue"], position=[0.5, 0.0, 0.0])
    with caplog.at_level(logging.WARNING):
        assert (
            node.parse_input("actuator_command", messages.actuator_command_from_joint_state, bad)
            is None
        )
    assert any(
        r.levelno == logging.WARNING
        and r.getMessage().startswith("actuator_command rejected: ")
        and "ur" in r.getMessage()
        for r in caplog.records
    )
    node.destroy_node()


def test_rejected_warnings_are_throttled_per_topic(caplog):
    """One warning per topic and REJECT_LOG_PERIOD_S of node (here: simulated) time."""
    rclpy.init(args=["n"])
    node = _Probe()
    f = messages.MsgFactory.rclpy()
    bad_cmd = messages.joint_state(f, 0, ["ut"], position=[0.5])
    bad_ref = messages.twist_reference_msg(f, 0, [1.0, 0.0, 0.0], 0.0, frame_id="map")

    def feed():
        for _ in range(3):
            assert (
                node.parse_input(
                    "actuator_command", messages.actuator_command_from_joint_state, bad_cmd
                )
                is None
            )
        assert (
            node.parse_input("velocity_reference", messages.reference_from_twist, bad_ref) is None
        )

    def warned():
        return [
            r.getMessage().split(":")[0] for r in caplog.records if r.levelno == logging.WARNING
        ]

    with caplog.at_level(logging.WARNING):
        feed()  # first of each topic is logged
        assert warned() == ["actuator_command rejected", "velocity_reference rejected"]
        ctx = rclpy.utilities.get_default_context()
        ctx._standin_now_ns += int(0.9e9)
        feed()  # within the period: silent
        assert len(warned()) == 2
        ctx._standin_now_ns += int(0.1e9)
        feed()  # period over: one more each
        assert warned() == ["actuator_command rejected", "velocity_reference rejected"] * 2
    node.destroy_node()
