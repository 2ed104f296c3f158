"""Stand-in for ``rclpy.logging``."""

from rclpy.impl.rcutils_logger import LoggingSeverity, RcutilsLogger  # noqa: F401


def get_logger(name):
    if not name:
        raise ValueError("Logger name must not be empty.")
    return RcutilsLogger(name)
