"""Stand-in for the ROS 2 Jazzy sensor_msgs package (message classes from the rosbags
typestore)."""
