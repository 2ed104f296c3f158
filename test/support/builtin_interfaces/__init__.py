"""Stand-in for the ROS 2 Jazzy builtin_interfaces package (message classes from the rosbags
typestore)."""
