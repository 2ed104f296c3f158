"""Phase 1 (seed 0 Sec. 3): PX4 baseline velocity control + excitation, logged.

    ros2 launch lpv_sysid phase1.launch.py [vertex:="[2.0, 0.0, 0.0]"] [config_dir:=...]

Nodes (namespace /lpv_sysid): excitation (phase-1 mode: vertex offset + multisine on
u, v, w and yaw rate), mavlink_bridge (velocity setpoints to PX4), data_logger.
One vertex per run: pass ``vertex`` (body velocity u, v, w in the seed's FRD frame,
m/s); run the file again for the next vertex of the box.
"""

from launch import LaunchDescription
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from lpv_sysid.nodes._common import LAUNCH_SIGTERM_TIMEOUT_S
from lpv_sysid.nodes.launch_util import declare_arguments, params

NAMESPACE = "lpv_sysid"
#: launch's SIGINT -> SIGTERM escalation (5 s by default) after the nodes' orderly shutdown
#: (nodes/_common.LAUNCH_SIGTERM_TIMEOUT_S); ``sigterm_timeout:=S`` overrides it
SIGTERM_TIMEOUT = LaunchConfiguration("sigterm_timeout", default=str(LAUNCH_SIGTERM_TIMEOUT_S))


def generate_launch_description():
    return LaunchDescription(
        [
            *declare_arguments(
                signals_file="signals.npz", vertex="[0.0, 0.0, 0.0]", log_dir="phase1_log"
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
                    {
                        "mode": "phase1",
                        "signals_file": LaunchConfiguration("signals_file"),
                        "vertex_frd": LaunchConfiguration("vertex"),
                    },
                ],
            ),
            Node(
                package="lpv_sysid",
                executable="mavlink_bridge_node",
                name="mavlink_bridge",
                namespace=NAMESPACE,
                output="screen",
                sigterm_timeout=SIGTERM_TIMEOUT,
                parameters=[params("mavlink_bridge_node.yaml"), {"command": "velocity"}],
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
                    {"out_dir": LaunchConfiguration("log_dir")},
                ],
            ),
        ]
    )
