"""Phase 2 (seed 0 Sec. 4): robust LPV control of the vehicle + excitation, logged.

    ros2 launch lpv_sysid phase2.launch.py gains_file:=gains.yaml [signals_file:=...]

Nodes (namespace /lpv_sysid): excitation (phase-2 mode: v_d(t) and u_e(t)),
lpv_controller (refuses to start on an invalid gains file), mavlink_bridge (actuator
commands to PX4; hands control back to PX4 when commands stop), data_logger.
"""

from launch import LaunchDescription
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from lpv_sysid.nodes._common import LAUNCH_SIGTERM_TIMEOUT_S
from lpv_sysid.nodes.launch_util import REQUIRED, declare_arguments, params

NAMESPACE = "lpv_sysid"
#: launch's SIGINT -> SIGTERM escalation (5 s by default) after the nodes' orderly shutdown
#: (nodes/_common.LAUNCH_SIGTERM_TIMEOUT_S); ``sigterm_timeout:=S`` overrides it
SIGTERM_TIMEOUT = LaunchConfiguration("sigterm_timeout", default=str(LAUNCH_SIGTERM_TIMEOUT_S))


def generate_launch_description():
    gains = LaunchConfiguration("gains_file")
    return LaunchDescription(
        [
            *declare_arguments(
                gains_file=REQUIRED, signals_file="signals.npz", log_dir="phase2_log"
            ),
            Node(
                package="lpv_sysid",
                executable="excitation_node",
                name="excitation",
                namespace=NAMESPACE,
                output="screen",
                sigterm_timeout=SIGTERM_TIMEOUT,
                parameters=[
                    params("excitation_node.yaml"),
                    {"mode": "phase2", "signals_file": LaunchConfiguration("signals_file")},
                ],
            ),
            Node(
                package="lpv_sysid",
                executable="lpv_controller_node",
                name="lpv_controller",
                namespace=NAMESPACE,
                output="screen",
                sigterm_timeout=SIGTERM_TIMEOUT,
                parameters=[params("lpv_controller.yaml"), {"gains_file": gains}],
            ),
            Node(
                package="lpv_sysid",
                executable="mavlink_bridge_node",
                name="mavlink_bridge",
                namespace=NAMESPACE,
                output="screen",
                sigterm_timeout=SIGTERM_TIMEOUT,
                parameters=[params("mavlink_bridge_node.yaml"), {"command": "attitude_rate"}],
            ),
            Node(
                package="lpv_sysid",
                executable="data_logger_node",
                name="data_logger",
                namespace=NAMESPACE,
                output="screen",
                sigterm_timeout=SIGTERM_TIMEOUT,
                parameters=[
                    params("data_logger.yaml"),
                    {"out_dir": LaunchConfiguration("log_dir"), "gains_file": gains},
                ],
            ),
        ]
    )
