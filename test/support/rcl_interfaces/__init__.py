"""Stand-in for the ROS 2 Jazzy rcl_interfaces package (message classes from the rosbags
typestore)."""
