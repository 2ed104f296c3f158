"""The vehicle's clock on the receiver's clock: when a sample was taken, not when it was read.

Every PX4 message with a boot time (``time_boot_ms``, ``time_usec``) left PX4 after its
clock read that value, so ``receive - t_vehicle`` over-estimates the offset between the
two clocks by the message's latency. :class:`VehicleClock` keeps the lower envelope of
that difference (the least-delayed message so far), allowed to rise at :data:`LIVE_RISE`
receiver seconds per vehicle second (a drifting crystal, or a lock-step SITL slowed by
load, drifts by far less), and maps a vehicle time onto the receiver's clock:
``local(t_vehicle) = t_vehicle + offset``, never later than the sample's receipt and
never more than :data:`MAX_AGE_S` before it (another time base, e.g. a wrapped counter).

Why it matters (issue 27): a link poll that runs late reads a backlog of states in one go;
stamped with the poll's clock they all get one stamp and look fresh, so a loop-delay
watchdog sees neither their true age nor their spacing. Stamped with the vehicle's time
mapped here, each keeps its own time and its real age.

A vehicle time that goes back by more than :data:`RESET_JUMP_S` is a reboot: the
estimate starts again.

Per ``stream`` (a caller's name for one kind of sample), the stamps never go back while the
vehicle times do not: when a less-delayed message lowers the envelope, the stream's offset
follows it down at most :data:`CATCH_UP` s per vehicle second, so consecutive stamps stay at
least half their vehicle spacing apart (measured under real Jazzy against PX4 SITL at load
10: a drop larger than two states' spacing stamped them 76 us backwards, and the controller's
out-of-order check aborted phase 2).

:class:`ReceiverClock` is for sample times already on the receiver's clock: MAVROS stamps
its messages with ROS time (the FCU time through its timesync offset, or its receipt time
with ``timesync_rate`` 0, MAVROS 2's default) -- the same clock as the bridge's. Mapped
through the lower envelope they got the rise allowance as an error: a bridge stalled for a
while raised the offset (stamps later than MAVROS's, the age under-stated) and the next
prompt sample dropped it again, a stamp up to 95 ms before its predecessor (measured in
the real phase-2 graph at load 15: the controller's out_of_order abort).

Example
-------
>>> c = VehicleClock()
>>> c.observe(100.030, 5.000)   # latency 30 ms
>>> c.observe(100.045, 5.040)   # latency 5 ms: the lower envelope
>>> round(c.local(5.020, 100.050), 3)
100.025
"""

from __future__ import annotations

import math

#: how fast the offset estimate may rise (receiver s per vehicle s)
LIVE_RISE = 0.05
#: how fast a stream's offset may fall to a lowered envelope (receiver s per vehicle s, < 1)
CATCH_UP = 0.5
#: vehicle time this far back: a reboot (matches the decoder's out-of-order rule)
RESET_JUMP_S = 10.0
#: a mapped time older than this is on another time base (a wrapped uint32 microsecond
#: counter): the sample keeps its receipt time
MAX_AGE_S = 2.0


class VehicleClock:
    """Lower-envelope offset between the vehicle's boot clock and the receiver's clock
    (module docstring). Times in seconds."""

    def __init__(self) -> None:
        self.offset: float | None = None  # receive - t_vehicle, lower envelope [s]
        self._tv = -math.inf  # newest vehicle time observed [s]
        self._last: dict[str, tuple[float, float]] = {}  # stream: (t_vehicle, offset) [s]

    def observe(self, now: float, t_vehicle: float) -> None:
        """One message received at ``now`` (receiver clock) stamped ``t_vehicle`` by PX4."""
        if not (math.isfinite(now) and math.isfinite(t_vehicle) and t_vehicle > 0.0):
            return
        est = now - t_vehicle
        if self.offset is None or t_vehicle < self._tv - RESET_JUMP_S:
            self.offset, self._tv = est, t_vehicle
            self._last.clear()
        else:
            rise = LIVE_RISE * max(0.0, t_vehicle - self._tv)
            self.offset = min(est, self.offset + rise)
            self._tv = max(self._tv, t_vehicle)

    def local(self, t_vehicle: float, received: float, stream: str | None = None) -> float:
        """Receiver-clock time of vehicle time ``t_vehicle`` for a sample read at
        ``received``: ``received`` itself before any estimate or for a time that is none,
        else ``t_vehicle + offset``, at most ``received``; with ``stream``, the offset falls
        at most :data:`CATCH_UP` per vehicle second from that stream's previous one (module
        docstring), so its stamps do not go back while its vehicle times do not."""
        if self.offset is None or not (math.isfinite(t_vehicle) and t_vehicle > 0.0):
            return received
        off = self.offset
        if stream is not None:
            tv_prev, off_prev = self._last.get(stream, (-math.inf, -math.inf))
            if t_vehicle >= tv_prev:
                off = max(off, off_prev - CATCH_UP * (t_vehicle - tv_prev))
                self._last[stream] = (t_vehicle, off)
        t = t_vehicle + off
        if t < received - MAX_AGE_S:
            return received
        return min(t, received)


class ReceiverClock(VehicleClock):
    """Sample times already on the receiver's clock (module docstring): kept as they are,
    never later than the sample's receipt nor more than :data:`MAX_AGE_S` before it."""

    def __init__(self) -> None:
        super().__init__()
        self.offset = 0.0

    def observe(self, now: float, t_vehicle: float) -> None:
        """Nothing to estimate: the offset is 0."""
