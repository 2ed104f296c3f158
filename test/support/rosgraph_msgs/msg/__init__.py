"""Stand-in rosgraph_msgs.msg: rclpy-like classes generated from the rosbags Jazzy typestore."""

from _rosmsg_standin import populate as _populate

_populate(globals(), "rosgraph_msgs", "msg")
del _populate
