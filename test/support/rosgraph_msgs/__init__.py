"""Stand-in for the ROS 2 Jazzy rosgraph_msgs package (Clock, from the rosbags typestore)."""
