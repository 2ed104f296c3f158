"""Stand-in for the ROS 2 Jazzy std_srvs package."""
