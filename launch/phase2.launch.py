"""Phase 2 (seed 0 Sec. 4): robust LPV control of the vehicle + excitation, logged.

    ros2 launch lpv_sysid phase2.launch.py gains_file:=gains.yaml signals_file:=signals.npz \
        link_url:=/dev/ttyAMA0 [namespace:=uav1] [log_dir:=phase2_log] [auto_start:=false]
    ros2 service call /lpv_sysid/sequencer/start std_srvs/srv/Trigger   # fly it
    ros2 service call /lpv_sysid/sequencer/abort std_srvs/srv/Trigger   # stop, hand back

Nodes (namespace ``namespace``): excitation (phase-2 mode: v_d(t) and u_e(t)), lpv_controller
(refuses to start on an invalid gains file), mavlink_bridge (rate + thrust setpoints to PX4;
hands control back to PX4 when commands stop), data_logger, and the sequencer, which starts
them in the safe order once called (or at once with ``auto_start:=true``): bridge ready (link
up) -> controller armed (commanding) -> bridge in OFFBOARD (confirmed by PX4) -> excitation;
a refusal, a timeout or an abort anywhere aborts every started node in reverse order.
``transport:=mavros`` carries velocity setpoints only (docs/px4_transport.md): phase 2
needs ``transport:=mavlink``.
"""

from launch import LaunchDescription
from lpv_sysid.flight.sequencer import PHASE2_STEPS
from lpv_sysid.nodes.launch_util import (
    LINK_URL_DEFAULT,
    REQUIRED,
    TRANSPORT_DEFAULT,
    arg,
    bridge_overrides,
    declare_arguments,
    node,
    sequencer,
)


def generate_launch_description():
    return LaunchDescription(
        [
            *declare_arguments(
                gains_file=REQUIRED,
                signals_file="signals.npz",
                log_dir="phase2_log",
                transport=TRANSPORT_DEFAULT,
                link_url=LINK_URL_DEFAULT,
                auto_start="false",
            ),
            node(
                "excitation",
                "excitation_node.yaml",
                {"mode": "phase2", "signals_file": arg("signals_file")},
            ),
            node("lpv_controller", "lpv_controller.yaml", {"gains_file": arg("gains_file")}),
            node(
                "mavlink_bridge",
                "mavlink_bridge_node.yaml",
                bridge_overrides(command="attitude_rate"),
            ),
            node(
                "data_logger",
                "data_logger.yaml",
                {"out_dir": arg("log_dir"), "gains_file": arg("gains_file")},
            ),
            sequencer(list(PHASE2_STEPS)),
        ]
    )
