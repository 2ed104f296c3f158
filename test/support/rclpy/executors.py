"""Stand-in for ``rclpy.executors`` on the simulated clock.

``spin_once`` runs at most one ready callback (timers first, then subscriptions, services,
clients). If nothing is ready it *waits*: the simulated clock advances to the next timer
due time when that is within ``timeout_sec`` (or ``timeout_sec`` is None), otherwise by
``timeout_sec``. Nothing to wait for and no timeout raises RuntimeError (a real executor
would block forever). When the clock reaches the time set with
``rclpy._standin.shutdown_at`` the context is shut down and the executor raises
ExternalShutdownException, as a real executor does on an external shutdown during its
wait; a spin_once on a context already shut down raises RCLError, as rclpy's does.
"""

from rclpy.utilities import get_default_context


class ExternalShutdownException(Exception):
    """Context has been shutdown."""


class ShutdownException(Exception):
    """Signal that executor was shut down."""


class TimeoutException(Exception):
    """Signal that a timeout occurred."""


class ConditionReachedException(Exception):
    """Future has been completed."""


class Executor:
    def __init__(self, *, context=None):
        self._context = get_default_context() if context is None else context
        self._nodes = []
        self._is_shutdown = False

    @property
    def context(self):
        return self._context

    def add_node(self, node):
        if node not in self._nodes:
            self._nodes.append(node)
            node._executor = self
            return True
        return False

    def remove_node(self, node):
        if node in self._nodes:
            self._nodes.remove(node)

    def get_nodes(self):
        return list(self._nodes)

    def shutdown(self, timeout_sec=None):
        self._is_shutdown = True
        return True

    def _ready_work(self):
        now = self._context._standin_now_ns
        timers = [t for n in self._nodes for t in n.timers if not t.is_canceled()]
        due = [t for t in timers if t._next_ns() <= now]
        if due:
            return min(due, key=lambda t: t._next_ns())
        for n in self._nodes:
            for s in n.subscriptions:
                if s._standin_ready():
                    return s
        for n in self._nodes:
            for s in n.services:
                if s._standin_ready():
                    return s
        for n in self._nodes:
            for c in n.clients:
                if c._standin_ready():
                    return c
        return None

    def _next_timer_ns(self):
        times = [t._next_ns() for n in self._nodes for t in n.timers if not t.is_canceled()]
        return min(times) if times else None

    def _advance_to(self, target_ns):
        ctx = self._context
        stop = ctx._standin_shutdown_at_ns
        if stop is not None and target_ns > stop:
            ctx._standin_now_ns = max(ctx._standin_now_ns, stop)
            ctx.try_shutdown()
            raise ExternalShutdownException()
        ctx._standin_now_ns = max(ctx._standin_now_ns, target_ns)

    def spin_once(self, timeout_sec=None):
        if not self._context.ok():
            # as rclpy: the wait set cannot be built on a shut-down context (RCLError);
            # ExternalShutdownException only when the shutdown comes during the wait
            from rclpy._params_file import RCLError

            raise RCLError(
                "failed to create wait set: the given context is not valid, "
                "either rcl_init() was not called or rcl_shutdown() was called."
            )
        if self._is_shutdown:
            raise ExternalShutdownException()
        work = self._ready_work()
        if work is None:
            now = self._context._standin_now_ns
            nxt = self._next_timer_ns()
            limit = (
                None if timeout_sec is None or timeout_sec < 0 else now + int(timeout_sec * 1e9)
            )
            if nxt is not None and (limit is None or nxt <= limit):
                self._advance_to(nxt)
                work = self._ready_work()
            elif limit is not None:
                self._advance_to(limit)
                return
            elif self._context._standin_shutdown_at_ns is not None:
                self._advance_to(self._context._standin_shutdown_at_ns + 1)
            else:
                raise RuntimeError(
                    "stand-in: spin_once() would block forever: nothing to wait for and no timeout"
                )
        if work is not None:
            work._standin_execute()

    def spin(self):
        while self._context.ok() and not self._is_shutdown:
            self.spin_once()

    def spin_until_future_complete(self, future, timeout_sec=None):
        if timeout_sec is None or timeout_sec < 0:
            while self._context.ok() and not future.done():
                self.spin_once()
            return
        end = self._context._standin_now_ns + int(timeout_sec * 1e9)
        while self._context.ok() and not future.done():
            remaining = end - self._context._standin_now_ns
            if remaining <= 0:
                return
            self.spin_once(timeout_sec=remaining / 1e9)

    def spin_once_until_future_complete(self, future, timeout_sec=None):
        self.spin_once(timeout_sec=timeout_sec)


class SingleThreadedExecutor(Executor):
    def __init__(self, *, context=None):
        super().__init__(context=context)


class MultiThreadedExecutor(Executor):
    """Runs callbacks one at a time in the stand-in (deterministic)."""

    def __init__(self, num_threads=None, *, context=None):
        super().__init__(context=context)
        self._num_threads = num_threads or 2
