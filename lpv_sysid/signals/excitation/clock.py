"""The time base of the excitation player (:mod:`lpv_sysid.signals.excitation.player`):
:class:`TimeOrderError` for a sample older than the last one (stale or out-of-order
input) or NaN, and :class:`MonotonicTime`, which maps a clock that may jump back (a node
clock under ``use_sim_time``) onto the monotonic time the player needs."""

from __future__ import annotations

import math
from typing import Optional

from lpv_sysid.errors import ConfigError, SafetyError


class TimeOrderError(SafetyError):
    """A sample time earlier than the previous one (stale or out-of-order input), or NaN."""


class MonotonicTime:
    """Maps a clock that may jump backwards onto a monotonic time base for the core.

    :meth:`map` returns ``(t_core, jump)``: ``t_core = t + offset`` never decreases; when
    ``t`` is earlier than the previous call (a node clock under ``use_sim_time`` restarted,
    a ROS time jump) the offset absorbs the jump (``t_core`` advances by ``period``) and
    ``jump`` is the size of the step back [s] (0.0 otherwise), so the caller can abort and the
    fade still completes in ``ramp`` of the clock's time."""

    def __init__(self, period: float) -> None:
        if not (math.isfinite(period) and period > 0):
            raise ConfigError(f"excitation: clock period must be > 0, got {period!r}")
        self.period = float(period)
        self.offset = 0.0
        self._last: Optional[float] = None

    def map(self, t: float) -> tuple[float, float]:
        t = float(t)
        if not math.isfinite(t):
            raise TimeOrderError(f"excitation: clock time {t} is not finite")
        jump = 0.0
        if self._last is not None and t + self.offset < self._last:
            jump = self._last - (t + self.offset)
            self.offset = self._last + self.period - t
        self._last = t + self.offset
        return self._last, jump
