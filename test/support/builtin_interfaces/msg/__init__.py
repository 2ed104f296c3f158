"""Stand-in builtin_interfaces.msg: rclpy-like classes generated from the rosbags Jazzy
typestore."""

from _rosmsg_standin import populate as _populate

_populate(globals(), "builtin_interfaces", "msg")
del _populate
