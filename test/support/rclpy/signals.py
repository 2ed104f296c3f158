"""Stand-in for ``rclpy.signals`` (Jazzy): the signal-handler options of ``rclpy.init``."""

import enum


class SignalHandlerOptions(enum.IntEnum):
    NO = 0
    SIGINT = 1
    SIGTERM = 2
    ALL = 3
