"""Stand-in for the ROS 2 Jazzy std_msgs package (message classes from the rosbags typestore)."""
