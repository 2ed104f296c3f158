"""Stand-in mavros_msgs (MAVROS 2.10 definitions of the types the MAVROS transport uses)."""
