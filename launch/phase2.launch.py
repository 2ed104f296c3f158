"""Phase 2 (seed 0 Sec. 4): robust LPV control of the vehicle + excitation, logged.

    ros2 launch lpv_sysid phase2.launch.py gains_file:=gains.yaml [signals_file:=...]

Nodes (namespace /lpv_sysid): excitation (phase-2 mode: v_d(t) and u_e(t)),
lpv_controller (refuses to start on an invalid gains file), mavlink_bridge (actuator
commands to PX4; hands control back to PX4 when commands stop), data_logger.
"""

from launch import LaunchDescription
from lpv_sysid.nodes.launch_util import (
    MAVROS_ARGUMENTS,
    REQUIRED,
    arg,
    declare_arguments,
    mavros_node,
    node,
    transport_overrides,
)


def generate_launch_description():
    return LaunchDescription(
        [
            *declare_arguments(
                gains_file=REQUIRED,
                signals_file="signals.npz",
                log_dir="phase2_log",
                **MAVROS_ARGUMENTS,
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
                {"command": "attitude_rate", **transport_overrides()},
            ),
            mavros_node(),
            node(
                "data_logger",
                "data_logger.yaml",
                {"out_dir": arg("log_dir"), "gains_file": arg("gains_file")},
            ),
        ]
    )
