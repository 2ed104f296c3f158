"""Either phase against the simulated quadrotor instead of PX4 (no hardware needed).

    ros2 launch lpv_sysid sim.launch.py phase:=1 [vertex:="[2.0, 0.0, 0.0]"]
    ros2 launch lpv_sysid sim.launch.py phase:=2 gains_file:=gains.yaml

sim_vehicle takes the bridge's place: it publishes state, rotor_speeds and imu, flies the
PX4-like baseline on velocity_reference in phase 1 and applies actuator_command in phase 2.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

from lpv_sysid.nodes.launch_util import declare_arguments, params

NAMESPACE = "lpv_sysid"


def generate_launch_description():
    phase = LaunchConfiguration("phase")
    is_phase2 = IfCondition(PythonExpression(["'", phase, "' == '2'"]))
    return LaunchDescription([
        DeclareLaunchArgument("phase", default_value="1", choices=["1", "2"],
                              description="1: baseline + excitation, 2: LPV controller"),
        *declare_arguments(signals_file="signals.npz", gains_file="gains.yaml",
                           vertex="[0.0, 0.0, 0.0]", log_dir="sim_log",
                           notes={"gains_file": "phase 2 only", "vertex": "phase 1 only"}),
        Node(package="lpv_sysid", executable="sim_vehicle_node", name="sim_vehicle",
             namespace=NAMESPACE, output="screen",
             parameters=[params("sim_vehicle.yaml"),
                         {"mode": PythonExpression(["'lpv' if '", phase, "' == '2' else 'baseline'"])}]),
        Node(package="lpv_sysid", executable="excitation_node", name="excitation",
             namespace=NAMESPACE, output="screen",
             parameters=[params("excitation_node.yaml"),
                         {"mode": PythonExpression(["'phase' + '", phase, "'"]),
                          "signals_file": LaunchConfiguration("signals_file"),
                          "vertex_frd": LaunchConfiguration("vertex")}]),
        Node(package="lpv_sysid", executable="lpv_controller_node", name="lpv_controller",
             namespace=NAMESPACE, output="screen", condition=is_phase2,
             parameters=[params("lpv_controller.yaml"),
                         {"gains_file": LaunchConfiguration("gains_file")}]),
        Node(package="lpv_sysid", executable="data_logger_node", name="data_logger",
             namespace=NAMESPACE, output="screen",
             parameters=[params("data_logger.yaml"),
                         {"out_dir": LaunchConfiguration("log_dir")}]),
    ])
