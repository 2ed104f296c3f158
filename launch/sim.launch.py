"""Either phase against the simulated quadrotor instead of PX4 (no hardware needed).

    ros2 launch lpv_sysid sim.launch.py phase:=1 [vertex:="[2.0, 0.0, 0.0]"]
    ros2 launch lpv_sysid sim.launch.py phase:=2 gains_file:=gains.yaml

sim_vehicle takes the bridge's place: it publishes state, rotor_speeds and imu, flies the
PX4-like baseline on velocity_reference in phase 1 and applies actuator_command in phase 2.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node

NAMESPACE = "lpv_sysid"


def generate_launch_description():
    share = get_package_share_directory("lpv_sysid")
    config_dir = LaunchConfiguration("config_dir")
    phase = LaunchConfiguration("phase")
    is_phase2 = IfCondition(PythonExpression(["'", phase, "' == '2'"]))

    def params(name):
        return PathJoinSubstitution([config_dir, name])

    return LaunchDescription([
        DeclareLaunchArgument("phase", default_value="1", choices=["1", "2"],
                              description="1: baseline + excitation, 2: LPV controller"),
        DeclareLaunchArgument("config_dir", default_value=os.path.join(share, "config"),
                              description="directory holding the node parameter files"),
        DeclareLaunchArgument("signals_file", default_value="signals.npz",
                              description="signals.npz written by `lpv-sysid signals`"),
        DeclareLaunchArgument("gains_file", default_value="gains.yaml",
                              description="gains.yaml (phase 2 only)"),
        DeclareLaunchArgument("vertex", default_value="[0.0, 0.0, 0.0]",
                              description="vertex body velocity (u, v, w) FRD, m/s, phase 1"),
        DeclareLaunchArgument("log_dir", default_value="sim_log",
                              description="experiment directory of the data logger"),
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
