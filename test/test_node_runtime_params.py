"""Parameters at run time (issue 24 item 1), through the rclpy stand-in (real rclpy:
test_ros_real.py): every node applies ``status_rate_hz`` when it is set (checked by the
rate of its ``status`` messages), refuses a value its settings declaration refuses (with
that reason), and declares every other parameter read-only, so ``ros2 param set`` is
refused instead of answering "successful" while the node keeps the start value."""

import os
import socket
from dataclasses import dataclass

import numpy as np
import pytest
import rclpy
import rclpy._standin as standin
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter

from lpv_sysid.configuration import parameters
from lpv_sysid.errors import ConfigError
from lpv_sysid.nodes import shell

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, "config")
NODES = {
    # node name: (module, class, params file)
    "lpv_controller": ("lpv_controller_node", "LpvControllerNode", "lpv_controller.yaml"),
    "excitation": ("excitation_node", "ExcitationNode", "excitation_node.yaml"),
    "data_logger": ("data_logger_node", "DataLoggerNode", "data_logger.yaml"),
    "mavlink_bridge": ("mavlink_bridge_node", "MavlinkBridgeNode", "mavlink_bridge_node.yaml"),
    "sim_vehicle": ("sim_vehicle_node", "SimVehicleNode", "sim_vehicle.yaml"),
    "campaign": ("campaign_node", "CampaignNode", None),
}


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    from lpv_test_gains import write_gains

    from lpv_sysid.signals.store import save_npz

    d = tmp_path_factory.mktemp("inputs")
    t = np.arange(0.0, 4.0, 0.02)
    save_npz(str(d / "s.npz"), t, np.zeros((t.size, 4)), ["u_ref", "v_ref", "w_ref", "r_ref"])
    return {
        "lpv_controller": {"gains_file": write_gains(d / "gains.yaml")},
        "excitation": {"signals_file": str(d / "s.npz")},
        "data_logger": {"out_dir": str(d / "log")},
        "mavlink_bridge": {"link.url": f"udpin:127.0.0.1:{_free_udp_port()}"},
        "sim_vehicle": {},
        "campaign": {
            "campaign_file": os.path.join(CONFIG, "campaign.yaml"),
            "signals_file": str(d / "s.npz"),
        },
    }


@pytest.fixture(autouse=True)
def fresh():
    standin.reset()
    yield
    rclpy.try_shutdown()


def _start(name, inputs):
    import importlib

    module, cls, yaml_file = NODES[name]
    args = ["n", "--ros-args"]
    if yaml_file:
        args += ["--params-file", os.path.join(CONFIG, yaml_file)]
    for k, v in inputs[name].items():
        args += ["-p", f"{k}:={v}"]
    rclpy.init(args=args)
    return getattr(importlib.import_module(f"lpv_sysid.nodes.{module}"), cls)()


def _status_count(node, listener, seconds):
    """Status messages of ``node`` (its own name in the array) in ``seconds`` of node time."""
    got = []
    sub = listener.create_subscription(
        DiagnosticArray,
        "/lpv_sysid/status",
        lambda m: got.extend(
            s for s in m.status if s.name.startswith(node.get_fully_qualified_name())
        ),
        shell.QOS_RELIABLE,  # volatile: only what is published from now on
    )
    standin.spin_nodes([node, listener], seconds)
    listener.destroy_subscription(sub)
    return len(got)


@pytest.mark.parametrize("name", sorted(NODES))
def test_status_rate_applies_at_run_time_and_the_rest_is_read_only(name, inputs):
    node = _start(name, inputs)
    listener = Node("listener")
    try:
        assert node.runtime_parameters == {"status_rate_hz"}
        before = node.get_parameter("status_rate_hz").value
        assert before <= 2.0
        n_before = _status_count(node, listener, 5.0)
        assert 5.0 * before - 2 <= n_before <= 5.0 * before + 2, n_before

        # a value the declaration refuses: rejected with the reason, nothing changes
        (res,) = node.set_parameters([Parameter("status_rate_hz", value=1000.0)])
        assert not res.successful and "out of range" in res.reason
        assert node.get_parameter("status_rate_hz").value == before

        # a valid one takes effect: ten times the status messages in the same node time
        (res,) = node.set_parameters([Parameter("status_rate_hz", value=10.0)])
        assert res.successful, res.reason
        assert node.params["status_rate_hz"] == 10.0
        n_after = _status_count(node, listener, 5.0)
        assert 48 <= n_after <= 52, n_after

        # status is transient local: a subscriber that joins late (``ros2 topic echo``)
        # receives the node's last status at once, without waiting for the next one
        late = []
        listener.create_subscription(
            DiagnosticArray,
            "/lpv_sysid/status",
            lambda m: late.extend(
                s for s in m.status if s.name.startswith(node.get_fully_qualified_name())
            ),
            shell.QOS_STATUS,  # what ros2 topic echo picks: the publishers' QoS
        )
        standin.spin_nodes([listener], 0.0)
        assert len(late) == 10  # the publisher's history (keep last 10), nothing newer

        # every other parameter: read-only, the set refused and the value kept
        for pname in node.params:
            if pname == "status_rate_hz":
                continue
            assert node.describe_parameter(pname).read_only, pname
            old = node.get_parameter(pname)
            (res,) = node.set_parameters([old])
            assert not res.successful and "read-only" in res.reason, (pname, res.reason)
            assert node.get_parameter(pname) is old  # not even replaced by an equal value
    finally:
        listener.destroy_node()
        node.destroy_node()


@dataclass(frozen=True)
class _RateSettings(parameters.Settings):
    """A settings class with a cross-field rule the rclpy range cannot express."""

    WHERE = "probe"
    rate_hz: float = parameters.double(50.0, "rate [Hz]", 1.0, 100.0)
    status_rate_hz: float = parameters.double(2.0, "status rate [Hz]", 0.1, 100.0)

    def validate(self):
        if self.status_rate_hz > self.rate_hz:
            self.fail(f"status_rate_hz {self.status_rate_hz:g} above rate_hz {self.rate_hz:g}")


class _Probe(shell.ShellNode):
    SETTINGS = _RateSettings

    def __init__(self, **kwargs):
        super().__init__("probe", shell.settings_table(_RateSettings), **kwargs)
        self.settings_from(self.params)
        self.applied = []
        self.status_timer(self.params["status_rate_hz"], lambda: None)

    def apply_parameters(self, settings, changes):
        super().apply_parameters(settings, changes)
        self.applied.append((settings, changes))


def test_a_value_the_settings_refuse_is_rejected_with_their_reason():
    rclpy.init(args=["n", "--ros-args", "-p", "rate_hz:=5.0"])
    node = _Probe()
    try:
        (res,) = node.set_parameters([Parameter("status_rate_hz", value=8.0)])
        assert not res.successful
        assert res.reason == "probe: status_rate_hz 8 above rate_hz 5"
        assert node.get_parameter("status_rate_hz").value == 2.0 and node.applied == []
        assert node._status_timer.timer_period_ns == 500_000_000
        (res,) = node.set_parameters([Parameter("status_rate_hz", value=4.0)])
        assert res.successful and node._status_timer.timer_period_ns == 250_000_000
        ((settings, changes),) = node.applied
        assert changes == {"status_rate_hz": 4.0} and settings.rate_hz == 5.0
        (res,) = node.set_parameters([Parameter("rate_hz", value=50.0)])
        assert not res.successful and res.reason == "Trying to set a read-only parameter: rate_hz."
        with pytest.raises(ConfigError):
            node.settings_from({**node.params, "status_rate_hz": 6.0})
    finally:
        node.destroy_node()
