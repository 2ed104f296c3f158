"""Phase 1 (seed 0 Sec. 3): PX4 baseline velocity control + excitation, logged.

    ros2 launch lpv_sysid phase1.launch.py [vertex:="[2.0, 0.0, 0.0]"] [config_dir:=...]

Nodes (namespace /lpv_sysid): excitation (phase-1 mode: vertex offset + multisine on
u, v, w and yaw rate), mavlink_bridge (velocity setpoints to PX4), data_logger.
One vertex per run: pass ``vertex`` (body velocity u, v, w in the seed's FRD frame,
m/s); run the file again for the next vertex of the box.
"""

from launch import LaunchDescription
from lpv_sysid.nodes.launch_util import (
    MAVROS_ARGUMENTS,
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
                signals_file="signals.npz",
                vertex="[0.0, 0.0, 0.0]",
                log_dir="phase1_log",
                **MAVROS_ARGUMENTS,
            ),
            node(
                "excitation",
                "excitation_node.yaml",
                {
                    "mode": "phase1",
                    "signals_file": arg("signals_file"),
                    "vertex_frd": arg("vertex"),
                },
            ),
            node(
                "mavlink_bridge",
                "mavlink_bridge_node.yaml",
                {"command": "velocity", **transport_overrides()},
            ),
            mavros_node(),
            node("data_logger", "data_logger.yaml", {"out_dir": arg("log_dir")}),
        ]
    )
