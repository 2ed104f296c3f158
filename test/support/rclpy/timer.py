"""Stand-in for ``rclpy.timer.Timer`` on the simulated clock."""

from rclpy._standin_entity import Entity
from rclpy.exceptions import InvalidHandle


class Timer(Entity):
    def __init__(
        self, callback, callback_group, timer_period_ns, clock, *, context=None, autostart=True
    ):
        self._context = context
        self._clock = clock
        self.callback = callback
        self.callback_group = callback_group
        self._period_ns = int(timer_period_ns)
        self._canceled = not autostart
        self._last_ns = context._standin_now_ns
        self._destroyed = False

    @property
    def clock(self):
        return self._clock

    @property
    def timer_period_ns(self):
        return self._period_ns

    @timer_period_ns.setter
    def timer_period_ns(self, value):
        self._period_ns = int(value)
        self._last_ns = self._context._standin_now_ns

    def is_ready(self):
        return not self._canceled and self._context._standin_now_ns >= self._next_ns()

    def is_canceled(self):
        return self._canceled

    def cancel(self):
        self._canceled = True

    def reset(self):
        if self._destroyed:
            raise InvalidHandle("timer destroyed")
        self._canceled = False
        self._last_ns = self._context._standin_now_ns

    def time_since_last_call(self):
        return self._context._standin_now_ns - self._last_ns

    def time_until_next_call(self):
        if self._canceled:
            return None
        return self._next_ns() - self._context._standin_now_ns

    def _next_ns(self):
        return self._last_ns + self._period_ns

    def _standin_execute(self):
        # rcl_timer_call: the next call is scheduled on the period grid; missed periods
        # are skipped (not queued), as in rcl.
        now = self._context._standin_now_ns
        nxt = self._next_ns()
        if self._period_ns > 0:
            missed = (now - nxt) // self._period_ns
            self._last_ns = nxt + missed * self._period_ns
        else:
            self._last_ns = now
        self.callback()

    def destroy(self):
        self._destroyed = True
        self._canceled = True
