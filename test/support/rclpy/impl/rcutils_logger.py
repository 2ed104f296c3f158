"""Stand-in for ``rclpy.impl.rcutils_logger.RcutilsLogger`` over Python ``logging``.

Log calls go to the Python logger of the same (dotted) name, so tests can use caplog.
Supported keyword arguments as in rclpy: ``once``, ``skip_first``, ``throttle_duration_sec``
(the latter uses ``throttle_time_source_type``, a Clock, as in rclpy).
"""

import enum
import logging


class LoggingSeverity(enum.IntEnum):
    UNSET = 0
    DEBUG = 10
    INFO = 20
    WARN = 30
    ERROR = 40
    FATAL = 50


_PY = {LoggingSeverity.DEBUG: logging.DEBUG, LoggingSeverity.INFO: logging.INFO,
       LoggingSeverity.WARN: logging.WARNING, LoggingSeverity.ERROR: logging.ERROR,
       LoggingSeverity.FATAL: logging.CRITICAL}
_VALID_KW = {"once", "skip_first", "throttle_duration_sec", "throttle_time_source_type"}


class RcutilsLogger:
    def __init__(self, name=""):
        self.name = name
        self._py = logging.getLogger(name or "rclpy")
        self._state = {}

    def get_child(self, name):
        if not name:
            raise ValueError("Child logger name must not be empty.")
        return RcutilsLogger(f"{self.name}.{name}" if self.name else name)

    def set_level(self, level):
        self._py.setLevel(_PY.get(LoggingSeverity(level), logging.NOTSET))

    def get_effective_level(self):
        lvl = self._py.getEffectiveLevel()
        for sev, py in _PY.items():
            if py >= lvl:
                return sev
        return LoggingSeverity.FATAL

    def is_enabled_for(self, severity):
        return self._py.isEnabledFor(_PY[LoggingSeverity(severity)])

    def log(self, message, severity, **kwargs):
        bad = set(kwargs) - _VALID_KW
        if bad:
            raise TypeError(f"invalid keyword arguments for logging: {sorted(bad)}")
        import inspect
        caller = inspect.stack()[2]
        key = (caller.filename, caller.lineno)
        st = self._state.setdefault(key, {"count": 0, "last": None})
        st["count"] += 1
        if kwargs.get("once") and st["count"] > 1:
            return False
        if kwargs.get("skip_first") and st["count"] == 1:
            return False
        period = kwargs.get("throttle_duration_sec")
        if period:
            clock = kwargs.get("throttle_time_source_type")
            if clock is None:
                from rclpy.clock import Clock
                clock = Clock()
            now = clock.now().nanoseconds
            if st["last"] is not None and now - st["last"] < period * 1e9:
                return False
            st["last"] = now
        if not self.is_enabled_for(severity):
            return False
        self._py.log(_PY[LoggingSeverity(severity)], "%s", message)
        return True

    def debug(self, message, **kwargs):
        return self.log(message, LoggingSeverity.DEBUG, **kwargs)

    def info(self, message, **kwargs):
        return self.log(message, LoggingSeverity.INFO, **kwargs)

    def warning(self, message, **kwargs):
        return self.log(message, LoggingSeverity.WARN, **kwargs)

    def warn(self, message, **kwargs):
        return self.log(message, LoggingSeverity.WARN, **kwargs)

    def error(self, message, **kwargs):
        return self.log(message, LoggingSeverity.ERROR, **kwargs)

    def fatal(self, message, **kwargs):
        return self.log(message, LoggingSeverity.FATAL, **kwargs)
