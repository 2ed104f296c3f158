"""Phase 2 (seed 0 Sec. 4): robust LPV control of the vehicle + excitation, logged.

    ros2 launch lpv_sysid phase2.launch.py gains_file:=gains.yaml signals_file:=signals.npz \
        link_url:=/dev/ttyAMA0 [transport:=mavros [mavros_ns:=/mavros] [fcu_url:=URL]] \
        [namespace:=uav1] [log_dir:=phase2_log] [auto_start:=false]
    ros2 service call /lpv_sysid/sequencer/start std_srvs/srv/Trigger   # fly it
    ros2 service call /lpv_sysid/sequencer/abort std_srvs/srv/Trigger   # stop, hand back
    ros2 launch lpv_sysid phase2.launch.py design:=rate_plant gains_file:=DIR/gains.yaml \
        signals_file:=DIR/signals/signals.npz          # PX4 >= 1.14 (the chain's rate plant)

Nodes (namespace ``namespace``): excitation (phase-2 mode: v_d(t) and u_e(t)), lpv_controller
(refuses to start on an invalid gains file or a signal outside the box / envelope / kappa;
the design -- virtual actuator or rate plant -- is read from the gains file), mavlink_bridge
(``attitude_rate`` inversion for the virtual-actuator design, ``rate_setpoint`` =
SET_ATTITUDE_TARGET thrust + body rates for the rate plant; hands control back to PX4 when
commands stop), data_logger, and the sequencer, which starts
them in the safe order once called (or at once with ``auto_start:=true``): bridge ready (link
up) -> controller armed (commanding) -> bridge in OFFBOARD (confirmed by PX4) -> excitation;
a refusal, a timeout or an abort anywhere aborts every started node in reverse order.
``transport:=mavros`` flies it through MAVROS (mavros_msgs: setpoint_raw/attitude;
docs/px4_transport.md), ``fcu_url:=...`` starts MAVROS here (SITL).
``design:=rate_plant`` picks config/lpv_controller_px4.yaml (the file `lpv-sysid fly
phase2` flies with) and the bridge's ``rate_setpoint`` command: no hand-edited
configuration.
"""

from launch import LaunchDescription
from lpv_sysid.flight.sequencer import PHASE2_STEPS
from lpv_sysid.nodes.launch_util import (
    LINK_URL_DEFAULT,
    MAVROS_ARGUMENTS,
    REQUIRED,
    TRANSPORT_DEFAULT,
    arg,
    bridge_overrides,
    by_design,
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
                gains_file=REQUIRED,
                signals_file="signals.npz",
                log_dir="phase2_log",
                design="virtual_actuator",
                transport=TRANSPORT_DEFAULT,
                link_url=LINK_URL_DEFAULT,
                auto_start="false",
                **MAVROS_ARGUMENTS,
            ),
            node(
                "excitation",
                "excitation_node.yaml",
                {
                    "mode": "phase2",
                    "signals_file": arg("signals_file"),
                    "gains_file": arg("gains_file"),
                },
            ),
            node(
                "lpv_controller",
                by_design("lpv_controller_px4.yaml", "lpv_controller.yaml"),
                {"gains_file": arg("gains_file"), "signals_file": arg("signals_file")},
            ),
            node(
                "mavlink_bridge",
                "mavlink_bridge_node.yaml",
                bridge_overrides(
                    command=by_design("rate_setpoint", "attitude_rate"), **mavros_overrides()
                ),
            ),
            mavros_node(),
            node(
                "data_logger",
                "data_logger.yaml",
                {"out_dir": arg("log_dir"), "gains_file": arg("gains_file")},
            ),
            sequencer(list(PHASE2_STEPS)),
        ]
    )
