"""Stand-in for ``rclpy.utilities``."""

import threading

from rclpy.context import Context

_default_context = None
_lock = threading.Lock()


def get_default_context(*, shutting_down=False):
    """As rclpy: ``shutting_down`` hands out the default context and forgets it, so the
    next ``rclpy.init()`` starts a new one (nodes keep the context they were made in)."""
    global _default_context
    with _lock:
        if _default_context is None:
            _default_context = Context()
        if shutting_down:
            old, _default_context = _default_context, _successor(_default_context)
            return old
        return _default_context


def _successor(old):
    """The next default context; the stand-in's simulated clock runs on in it."""
    new = Context()
    new._standin_now_ns = old._standin_now_ns
    return new


def _reset_default_context():
    """Stand-in helper: a fresh default context (each test gets clean state)."""
    global _default_context
    with _lock:
        _default_context = Context()
        return _default_context


def ok(*, context=None):
    return (context or get_default_context()).ok()


def shutdown(*, context=None, uninstall_handlers=None):
    (context or get_default_context(shutting_down=True)).shutdown()


def try_shutdown(*, context=None, uninstall_handlers=None):
    """As rclpy: the default context is shut down (if it runs) and replaced by a new one."""
    global _default_context
    if context is not None:
        context.try_shutdown()
        return
    with _lock:
        if _default_context is None:
            _default_context = Context()
        _default_context.try_shutdown()
        if not _default_context.ok():
            _default_context = _successor(_default_context)


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
