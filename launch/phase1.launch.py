"""Phase 1 (seed 0 Sec. 3): PX4 baseline velocity control + excitation, logged.

    ros2 launch lpv_sysid phase1.launch.py vertex:="[2.0, 0.0, 0.0]" \
        signals_file:=signals.npz link_url:=/dev/ttyAMA0 \
        [transport:=mavros [mavros_ns:=/mavros] [fcu_url:=URL tgt_system:=N]] \
        [namespace:=uav1] [log_dir:=phase1_log] [auto_start:=false]
    ros2 service call /lpv_sysid/sequencer/start std_srvs/srv/Trigger   # fly the run
    ros2 service call /lpv_sysid/sequencer/abort std_srvs/srv/Trigger   # stop, hand back

Nodes (namespace ``namespace``): excitation (phase-1 mode: vertex offset + multisine on
u, v, w and yaw rate; streams the vertex reference before it starts), mavlink_bridge
(velocity setpoints to PX4 over ``transport`` / ``link_url``), data_logger, and the
sequencer, which starts them in the safe order once called (or at once with
``auto_start:=true``): the bridge (pre-stream, OFFBOARD confirmed by PX4's HEARTBEAT), then
the excitation; a refusal, a timeout or an abort anywhere aborts both (hand-back to PX4).
One vertex per run: pass ``vertex`` (body velocity u, v, w in the seed's FRD frame, m/s);
run the file again for the next vertex of the box (or fly them all: campaign.launch.py).
"""

from launch import LaunchDescription
from lpv_sysid.flight.sequencer import PHASE1_STEPS
from lpv_sysid.nodes.launch_util import (
    LINK_URL_DEFAULT,
    MAVROS_ARGUMENTS,
    TRANSPORT_DEFAULT,
    arg,
    bridge_overrides,
    declare_arguments,
    mavros_node,
    mavros_overrides,
    node,
    sequencer,
)


def generate_launch_description():
    return LaunchDescription(
        [
            *declare_arguments(
                signals_file="signals.npz",
                vertex="[0.0, 0.0, 0.0]",
                log_dir="phase1_log",
                transport=TRANSPORT_DEFAULT,
                link_url=LINK_URL_DEFAULT,
                auto_start="false",
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
                bridge_overrides(command="velocity", **mavros_overrides()),
            ),
            mavros_node(),
            node("data_logger", "data_logger.yaml", {"out_dir": arg("log_dir")}),
            sequencer(list(PHASE1_STEPS)),
        ]
    )
