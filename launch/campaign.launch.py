"""The whole phase-1 campaign (seed 0 Sec. IV) on PX4: take-off, every vertex, hover, hand-back.

    ros2 launch lpv_sysid campaign.launch.py [campaign_file:=...] [signals_file:=signals.npz] \
        [runs_dir:=campaign_runs] [log_dir:=campaign_log] [link_url:=/dev/ttyAMA0] \
        [namespace:=uav1]
    ros2 service call /lpv_sysid/campaign/start std_srvs/srv/Trigger      # fly it
    ros2 service call /lpv_sysid/campaign/abort std_srvs/srv/Trigger      # stop, hand back

Nodes (namespace /lpv_sysid): mavlink_bridge (velocity setpoints to PX4, arming on start,
safety envelope), campaign (lpv_sysid/nodes/campaign_node.py: the sequence, one rosbag2
per run in ``runs_dir`` for ``lpv-sysid identify``), data_logger (the whole flight in
``log_dir``). Check the vehicle first: ``lpv-sysid preflight --connect ...``. The ROS path
ends with the bridge's hand-back (HOLD); ``lpv-sysid fly phase1`` also lands.
"""

import os

from launch.actions import DeclareLaunchArgument

from launch import LaunchDescription
from lpv_sysid.configuration.defaults import share_config_dir
from lpv_sysid.nodes.launch_util import (
    LINK_URL_DEFAULT,
    arg,
    bridge_overrides,
    declare_arguments,
    node,
)


def generate_launch_description():
    return LaunchDescription(
        [
            *declare_arguments(
                signals_file="",
                log_dir="campaign_log",
                link_url=LINK_URL_DEFAULT,
                notes={"signals_file": "empty: designed from the campaign's signals_config"},
            ),
            DeclareLaunchArgument(
                "campaign_file",
                default_value=os.path.join(share_config_dir(), "campaign.yaml"),
                description="config/campaign.yaml: box, altitude window, timeouts",
            ),
            DeclareLaunchArgument(
                "runs_dir",
                default_value="campaign_runs",
                description="one rosbag2 per run (trim + excitation) for `lpv-sysid identify`",
            ),
            node(
                "mavlink_bridge",
                "mavlink_bridge_node.yaml",
                {
                    **bridge_overrides(),
                    "transport": "mavlink",  # the campaign arms and takes off: MAVLink only
                    "command": "velocity",
                    "velocity_frame": "body_ned",
                    "offboard.arm": True,
                },
            ),
            node(
                "campaign",
                overrides={
                    "campaign_file": arg("campaign_file"),
                    "signals_file": arg("signals_file"),
                    "out_dir": arg("runs_dir"),
                },
            ),
            node("data_logger", "data_logger.yaml", {"out_dir": arg("log_dir")}),
        ]
    )
