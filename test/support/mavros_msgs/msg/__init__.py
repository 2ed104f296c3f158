"""Stand-in mavros_msgs.msg: rclpy-like classes of the registered MAVROS 2.10 definitions."""

from _rosmsg_standin import populate as _populate

_populate(globals(), "mavros_msgs", "msg")
del _populate
