"""Stand-in for ``rclpy.impl.rcutils_logger.RcutilsLogger`` over Python ``logging``.

Log calls go to the Python logger of the same (dotted) name, so tests can use caplog.
Supported keyword arguments as in rclpy: ``once``, ``skip_first``, ``throttle_duration_sec``
(the latter uses ``throttle_time_source_type``, a Clock, as in rclpy). As rclpy, each call
site (function, file, line, bytecode offset) keeps one context: a call site that changes
its severity, logger name or filters raises ``ValueError`` (under real Jazzy the bridge died
with "Logger severity cannot be changed between calls." at its first warning after an info
from the same line).
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


_PY = {
    LoggingSeverity.DEBUG: logging.DEBUG,
    LoggingSeverity.INFO: logging.INFO,
    LoggingSeverity.WARN: logging.WARNING,
    LoggingSeverity.ERROR: logging.ERROR,
    LoggingSeverity.FATAL: logging.CRITICAL,
}
#: filter -> {parameter: default} as rclpy (None: required); the order is rclpy's
_FILTERS = {
    "throttle": {"throttle_duration_sec": None, "throttle_time_source_type": "clock"},
    "skip_first": {"skip_first": None},
    "once": {"once": None},
}


def _filters_from_kwargs(kwargs):
    """rclpy's get_filters_from_kwargs: the filters named by truthy keyword arguments."""
    detected = [name for name, params in _FILTERS.items() if any(kwargs.get(p) for p in params)]
    known = [p for params in _FILTERS.values() for p in params]
    for name in detected:
        for p, default in _FILTERS[name].items():
            if p not in kwargs and default is None:
                raise TypeError(
                    f'required parameter "{p}" not specified but is required for '
                    f'the the logging filter "{name}"'
                )
    for k in kwargs:
        if k not in known:
            raise TypeError(
                f'parameter "{k}" is not one of the recognized logging options "{known}"'
            )
    return detected


def _caller():
    """rclpy's CallerId: the first frame outside the logging modules, keyed by function,
    file, line and bytecode offset (two calls on one line are two callers)."""
    import inspect
    import os

    here = {
        os.path.realpath(__file__),
        os.path.realpath(os.path.join(os.path.dirname(__file__), "..", "logging.py")),
    }
    frame = inspect.currentframe()
    while os.path.realpath(frame.f_code.co_filename) in here:
        frame = frame.f_back
    return (
        frame.f_code.co_name,
        os.path.abspath(frame.f_code.co_filename),
        frame.f_lineno,
        frame.f_lasti,
    )


#: rcutils logger levels set with set_level, by logger name ("" = the default logger)
_LEVELS = {}


class RcutilsLogger:
    def __init__(self, name=""):
        self.name = name
        self._py = logging.getLogger(name or "rclpy")
        self.contexts = {}

    def get_child(self, name):
        if not name:
            raise ValueError("Child logger name must not be empty.")
        return RcutilsLogger(f"{self.name}.{name}" if self.name else name)

    def set_level(self, level):
        _LEVELS[self.name] = LoggingSeverity(level)

    def get_effective_level(self):
        """As rcutils: the level set on this logger or its nearest dotted ancestor, else
        the default logger's (INFO unless set). Python logging levels only filter what the
        stand-in prints (caplog), never which rclpy calls count."""
        name = self.name
        while name:
            if _LEVELS.get(name, LoggingSeverity.UNSET) != LoggingSeverity.UNSET:
                return _LEVELS[name]
            name = name.rpartition(".")[0]
        return _LEVELS.get("", LoggingSeverity.INFO)

    def is_enabled_for(self, severity):
        return LoggingSeverity(severity) >= self.get_effective_level()

    def log(self, message, severity, **kwargs):
        """As rclpy: filters only when enabled for ``severity``; one context per call site
        (rclpy raises ValueError when a call site changes its severity, logger name or
        filters: a line that logs INFO and later ERROR kills a real node)."""
        if not self.is_enabled_for(severity):
            return False
        severity = LoggingSeverity(severity)
        name = kwargs.pop("name", self.name)
        filters = _filters_from_kwargs(kwargs)
        key = _caller()
        ctx = self.contexts.get(key)
        if ctx is None:
            ctx = {
                "name": name,
                "severity": severity,
                "filters": filters,
                "params": {p: kwargs.get(p, d) for f in filters for p, d in _FILTERS[f].items()},
                "logged_once": False,
                "first_skipped": False,
                "last_ns": 0,
            }
            self.contexts[key] = ctx
        else:
            if severity != ctx["severity"]:
                raise ValueError("Logger severity cannot be changed between calls.")
            if name != ctx["name"]:
                raise ValueError("Logger name cannot be changed between calls.")
            if filters != ctx["filters"]:
                raise ValueError("Requested logging filters cannot be changed between calls.")
            if any(
                ctx["params"][p] != kwargs.get(p, d)
                for f in filters
                for p, d in _FILTERS[f].items()
            ):
                raise ValueError("Logging filter parameters cannot be changed between calls.")
        for f in ctx["filters"]:
            if not self._should_log(f, ctx, kwargs):
                return False
        self._py.log(_PY[severity], "%s", message)
        return True

    @staticmethod
    def _should_log(name, ctx, kwargs):
        if name == "once":
            first, ctx["logged_once"] = not ctx["logged_once"], True
            return first
        if name == "skip_first":
            skipped, ctx["first_skipped"] = ctx["first_skipped"], True
            return skipped
        clock = kwargs.get("throttle_time_source_type")
        if clock is None:
            from rclpy.clock import Clock

            clock = Clock()
        now = clock.now().nanoseconds
        if now >= ctx["last_ns"] + ctx["params"]["throttle_duration_sec"] * 1e9:
            ctx["last_ns"] = now
            return True
        return False

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
