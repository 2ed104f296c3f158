"""Stand-in for ``rclpy.duration``."""

import builtin_interfaces.msg

S_TO_NS = 1000 * 1000 * 1000


class Duration:
    def __init__(self, *, seconds=0, nanoseconds=0):
        total = int(seconds * S_TO_NS) + int(nanoseconds)
        if not -(2**63) <= total < 2**63:
            raise OverflowError("Total nanoseconds value is too large to store in C duration.")
        self._nanoseconds = total

    @property
    def nanoseconds(self):
        return self._nanoseconds

    def __repr__(self):
        return f"Duration(nanoseconds={self._nanoseconds})"

    def __eq__(self, other):
        if isinstance(other, Duration):
            return self._nanoseconds == other._nanoseconds
        raise TypeError("Can't compare duration with object of type: ", type(other))

    def __lt__(self, other):
        if isinstance(other, Duration):
            return self._nanoseconds < other._nanoseconds
        return NotImplemented

    def __le__(self, other):
        return self == other or self < other

    def __gt__(self, other):
        return not self <= other

    def __ge__(self, other):
        return not self < other

    __hash__ = None

    def to_msg(self):
        sec, ns = divmod(self._nanoseconds, S_TO_NS)
        return builtin_interfaces.msg.Duration(sec=int(sec), nanosec=int(ns))

    @classmethod
    def from_msg(cls, msg):
        return cls(seconds=msg.sec, nanoseconds=msg.nanosec)
