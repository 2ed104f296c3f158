"""Stand-in geographic_msgs.msg: rclpy-like classes (GeoPoint)."""

from _rosmsg_standin import populate as _populate

_populate(globals(), "geographic_msgs", "msg")
del _populate
