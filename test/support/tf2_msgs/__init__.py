"""Stand-in for the ROS 2 Jazzy tf2_msgs package (message classes from the rosbags
typestore)."""
