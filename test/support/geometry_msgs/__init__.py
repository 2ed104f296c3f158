"""Stand-in for the ROS 2 Jazzy geometry_msgs package (message classes from the rosbags
typestore)."""
