"""Stand-in for the ROS 2 Jazzy diagnostic_msgs package (message classes from the rosbags
typestore)."""
