"""Closing a :class:`~lpv_sysid.io.recorder.Recorder` cleanly on SIGINT/SIGTERM in a
process without rclpy's signal handling (tests, CLI): :func:`stop_on_signals`."""

from __future__ import annotations

import contextlib
import signal
from typing import TYPE_CHECKING, Callable

if TYPE_CHECKING:
    from lpv_sysid.io.recorder.recorder import Recorder


@contextlib.contextmanager
def stop_on_signals(
    recorder: Recorder,
    stamp_ns: Callable[[], int] | None = None,
    signals=(signal.SIGINT, signal.SIGTERM),
):
    """Close ``recorder`` cleanly on SIGINT/SIGTERM, then exit (status 128 + signo).

    For processes that own the recorder without rclpy's signal handling (tests, CLI).
    """
    previous = {}

    def handler(signo, _frame):
        # Never close the bag from inside a half-done write: if the signal interrupted
        # record(), it exits once that message is complete; the finally below closes.
        recorder._exit_code = 128 + signo
        if not recorder._busy:
            raise SystemExit(128 + signo)

    for s in signals:
        previous[s] = signal.signal(s, handler)
    try:
        yield recorder
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        recorder.stop(stamp_ns() if stamp_ns else None)
