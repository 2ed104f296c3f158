"""Stand-in for ``rclpy.clock``: every clock reads the context's simulated time.

The stand-in has no wall clock: time only moves when an executor waits (``spin_once``
with a timeout or until the next timer is due), so timers fire deterministically.
"""

from rclpy.clock_type import ClockType
from rclpy.time import Time


class Clock:
    def __init__(self, *, clock_type=ClockType.SYSTEM_TIME, _context=None):
        if not isinstance(clock_type, ClockType):
            raise TypeError("Clock type must be a ClockType enum")
        self._clock_type = clock_type
        self._context = _context

    @property
    def clock_type(self):
        return self._clock_type

    def now(self):
        from rclpy.utilities import get_default_context

        ctx = self._context or get_default_context()
        return Time(nanoseconds=ctx._standin_now_ns, clock_type=self._clock_type)

    def __repr__(self):
        return f"Clock(clock_type={self._clock_type.name})"


class ROSClock(Clock):
    def __init__(self, _context=None):
        super().__init__(clock_type=ClockType.ROS_TIME, _context=_context)

    @property
    def ros_time_is_active(self):
        return False
