"""Stand-in for ``rclpy.utilities``."""

import threading

from rclpy.context import Context

_default_context = None
_lock = threading.Lock()


def get_default_context(*, shutting_down=False):
    global _default_context
    with _lock:
        if _default_context is None:
            _default_context = Context()
        return _default_context


def _reset_default_context():
    """Stand-in helper: a fresh default context (each test gets clean state)."""
    global _default_context
    with _lock:
        _default_context = Context()
        return _default_context


def ok(*, context=None):
    return (context or get_default_context()).ok()


def shutdown(*, context=None, uninstall_handlers=None):
    (context or get_default_context()).shutdown()


def try_shutdown(*, context=None, uninstall_handlers=None):
    (context or get_default_context()).try_shutdown()


def remove_ros_args(args=None):
    args = list(args or [])
    out, in_ros = [], False
    for a in args:
        if a == "--ros-args":
            in_ros = True
        elif a == "--" and in_ros:
            in_ros = False
        elif not in_ros:
            out.append(a)
    return out
