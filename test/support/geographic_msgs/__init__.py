"""Stand-in geographic_msgs (GeoPoint, for mavros_msgs/HomePosition)."""
