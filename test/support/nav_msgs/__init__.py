"""Stand-in for the ROS 2 Jazzy nav_msgs package (message classes from the rosbags typestore)."""
