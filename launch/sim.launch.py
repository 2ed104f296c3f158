"""Either phase against the simulated quadrotor instead of PX4 (no hardware needed).

    ros2 launch lpv_sysid sim.launch.py phase:=1 [vertex:="[2.0, 0.0, 0.0]"]
    ros2 launch lpv_sysid sim.launch.py phase:=2 gains_file:=gains.yaml

sim_vehicle takes the bridge's place: it publishes state, rotor_speeds and imu, flies the
PX4-like baseline on velocity_reference in phase 1 and applies actuator_command in phase 2.

The graph runs on simulation time: sim_vehicle (``lockstep``) publishes ``/clock`` from its
physics time, every other node has ``use_sim_time``, and the controller steps its law on each
state sample (``tick_source: state``); sim_vehicle integrates past a state sample only once the
command computed on it arrived (the controller's ``lockstep``: before its start and after an
abort it answers each state sample on ``lockstep_ack`` instead, so sim time never runs ahead
of it). The controller follows the 100 Hz reference along its slope
between messages (``reference_hold: foh``), as the offline simulation samples the signal.
So the loop samples exactly like the offline ``lpv-sysid simulate phase2`` however loaded
the machine is (a wall-clock Python graph on 2 loaded cores had more loop delay than the demo
gains tolerate); the wall time of a run stretches instead (real-time factor 0.7 at load ~9
on 2 cores: the 104 s signal in ~150 s, test/test_ros_phase2.py).
The sequencer starts the nodes in the safe order on its ``start`` service (or at once with
``auto_start:=true``): phase 1 the excitation; phase 2 the controller (confirmed armed), then
the excitation:

    ros2 service call /lpv_sysid/sequencer/start std_srvs/srv/Trigger
"""

from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import PythonExpression

from launch import LaunchDescription
from lpv_sysid.nodes.launch_util import arg, declare_arguments, node, sequencer

#: every node but sim_vehicle (the clock source) runs on its /clock
SIM_TIME = {"use_sim_time": True}
#: the simulation's clock in the graph's namespace (two simulated graphs side by side do
#: not share one /clock): sim_vehicle publishes it there, every node reads it from there
CLOCK = [("/clock", ["/", arg("namespace"), "/clock"])]


def generate_launch_description():
    phase = arg("phase")
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "phase",
                default_value="1",
                choices=["1", "2"],
                description="1: baseline + excitation, 2: LPV controller",
            ),
            *declare_arguments(
                signals_file="signals.npz",
                gains_file="gains.yaml",
                vertex="[0.0, 0.0, 0.0]",
                log_dir="sim_log",
                auto_start="false",
                notes={"gains_file": "phase 2 only", "vertex": "phase 1 only"},
            ),
            node(
                "sim_vehicle",
                "sim_vehicle.yaml",
                {
                    "mode": PythonExpression(["'lpv' if '", phase, "' == '2' else 'baseline'"]),
                    "lockstep": True,
                },
                remappings=CLOCK,
            ),
            node(
                "excitation",
                "excitation_node.yaml",
                {
                    "mode": PythonExpression(["'phase' + '", phase, "'"]),
                    "signals_file": arg("signals_file"),
                    "vertex_frd": arg("vertex"),
                    **SIM_TIME,
                },
                remappings=CLOCK,
            ),
            node(
                "lpv_controller",
                "lpv_controller.yaml",
                {
                    "gains_file": arg("gains_file"),
                    "tick_source": "state",
                    # answer every state sample, started or not (lockstep_ack while not
                    # commanding): the simulation never runs past a sample the controller has
                    # not processed, also between its start and its first command
                    "lockstep": True,
                    "reference_hold": "foh",
                    # lock-stepped: the simulated vehicle waits for the command of each state,
                    # so in sim time a command acts on a state at most one period old; the
                    # configured loop delay (10 ms + 1 / state_rate_hz) must fit the gains'
                    # certificate.loop_delay.bound_s (checked at start)
                    "input_latency_s": 0.01,
                    **SIM_TIME,
                },
                condition=IfCondition(PythonExpression(["'", phase, "' == '2'"])),
                remappings=CLOCK,
            ),
            node(
                "data_logger",
                "data_logger.yaml",
                {"out_dir": arg("log_dir"), **SIM_TIME},
                remappings=CLOCK,
            ),
            # no bridge in the simulation: phase 1 starts the excitation, phase 2 the
            # controller (armed) and then the excitation
            sequencer(
                PythonExpression(
                    [
                        "'[lpv_controller, excitation]' if '",
                        phase,
                        "' == '2' else '[excitation]'",
                    ]
                ),
                remappings=CLOCK,
                **SIM_TIME,
            ),
        ]
    )
