"""Stand-in tf2_msgs.msg: rclpy-like classes generated from the rosbags Jazzy typestore."""

from _rosmsg_standin import populate as _populate

_populate(globals(), "tf2_msgs", "msg")
del _populate
