"""A single-threaded rclpy executor with a per-wake cost near rcl's (issue 27).

rclpy's :class:`~rclpy.executors.SingleThreadedExecutor` (Jazzy, rclpy 7.1) rebuilds its
wait set in Python on every wake: it filters every entity of the node through its callback
group, enters each handle in an ``ExitStack``, adds every QoS-event handler (two per
publisher and subscription), creates an rcl timer for the ``spin_once`` timeout, and wraps
each callback in a :class:`~rclpy.task.Task` coroutine. Profiled through real rclpy, the
controller node in the vehicle configuration (state 250 Hz, three inputs at 100 Hz, the
250 Hz law timer: ~800 wakes/s) spent most of its Python time there, not in its callbacks.

:class:`LeanExecutor` runs the same callbacks, in the same order per wake (timers, then
subscriptions, guard conditions, clients and services, as rclpy does), one thread,
synchronous callbacks only:

- one rcl wait set, allocated when the node's entities change (rclpy's nodes call
  :meth:`LeanExecutor.wake` then) and refilled per wake (a C call per handle);
- the ``spin_once`` timeout passed to ``rcl_wait`` itself (no rcl timer per wake);
- a callback called directly (no Task); a coroutine callback is refused (RuntimeError);
- QoS-event handlers (incompatible QoS / type warnings) kept, taken and run as rclpy does.

What it does not do (nothing of the package's nodes that use it needs it): callback groups
(every callback runs to completion before the next, as in a SingleThreadedExecutor with the
default mutually exclusive group), ``spin_until_future_complete``, several threads.
``shell.run`` picks it for a node whose class sets ``EXECUTOR = LeanExecutor``.
"""

from __future__ import annotations

from typing import Any, Optional

from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.utilities import get_default_context

try:  # a real rclpy: the rcl wait set
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
    from rclpy.subscription import Subscription

    _MESSAGE_ONLY: Any = Subscription.CallbackType.MessageOnly
except ImportError:  # the tests' rclpy stand-in (simulated clock): no rcl underneath
    _rclpy = None
    _MESSAGE_ONLY = None


def _run(coro) -> None:
    """Run an ``async def`` that never suspends (rclpy's event handlers, ``waitable.execute``)."""
    try:
        coro.send(None)
    except StopIteration:
        return
    coro.close()
    raise RuntimeError("LeanExecutor: an asynchronous callback suspended (not supported)")


class LeanExecutor:
    """See module docstring. The part of rclpy's Executor interface the shells use:
    ``add_node``, ``remove_node``, ``get_nodes``, ``spin_once``, ``wake``, ``shutdown``."""

    def __init__(self, *, context: Any = None) -> None:
        if _rclpy is None:
            raise RuntimeError("LeanExecutor needs a real rclpy (an rcl wait set)")
        self._context = get_default_context() if context is None else context
        self._nodes: list = []
        self._dirty = True
        self._ws: Any = None
        self._subs: list = []
        self._timers: list = []
        self._services: list = []
        self._clients: list = []
        self._guards: list = []
        self._waitables: list = []

    # -- the Executor interface the shells use ---------------------------------------
    def add_node(self, node) -> bool:
        if node in self._nodes:
            return False
        self._nodes.append(node)
        self._dirty = True
        node.executor = self  # rclpy's nodes call wake() when an entity comes or goes
        return True

    def remove_node(self, node) -> None:
        if node in self._nodes:
            self._nodes.remove(node)
            self._dirty = True
            node.executor = None

    def get_nodes(self) -> list:
        return list(self._nodes)

    def wake(self) -> None:
        """An entity of a node was created or destroyed (rclpy's nodes call this): the wait
        set is rebuilt before the next wait (this executor waits in the thread that adds
        entities, so no wait is interrupted)."""
        self._dirty = True

    def shutdown(self, timeout_sec: Optional[float] = None) -> bool:
        for node in list(self._nodes):
            self.remove_node(node)
        self._ws = None
        return True

    # -- the wait set --------------------------------------------------------------
    def _rebuild(self) -> None:
        subs, timers, services, clients, guards, waitables = [], [], [], [], [], []
        for n in self._nodes:
            subs += list(n.subscriptions)
            timers += list(n.timers)
            services += list(n.services)
            clients += list(n.clients)
            guards += list(n.guards)
            waitables += list(n.waitables)
        extra = [w.get_num_entities() for w in waitables]
        self._ws = _rclpy.WaitSet(
            len(subs) + sum(e.num_subscriptions for e in extra),
            len(guards) + sum(e.num_guard_conditions for e in extra),
            len(timers) + sum(e.num_timers for e in extra),
            len(clients) + sum(e.num_clients for e in extra),
            len(services) + sum(e.num_services for e in extra),
            sum(e.num_events for e in extra),
            self._context.handle,
        )
        # (handle, entity) pairs: rclpy reports ready entities by handle pointer
        self._subs = [(s.handle, s) for s in subs]
        self._timers = [(t.handle, t) for t in timers]
        self._services = [(s.handle, s) for s in services]
        self._clients = [(c.handle, c) for c in clients]
        self._guards = [(g.handle, g) for g in guards]
        self._waitables = waitables
        self._dirty = False

    def spin_once(self, timeout_sec: Optional[float] = None) -> None:
        """Wait up to ``timeout_sec`` (None: forever) and run every callback that is ready."""
        if self._dirty:
            self._rebuild()
        ws = self._ws
        ws.clear_entities()
        for h, _ in self._subs:
            ws.add_subscription(h)
        for h, _ in self._timers:
            ws.add_timer(h)
        for h, _ in self._services:
            ws.add_service(h)
        for h, _ in self._clients:
            ws.add_client(h)
        for h, _ in self._guards:
            ws.add_guard_condition(h)
        for w in self._waitables:
            w.add_to_wait_set(ws)
        ws.wait(-1 if timeout_sec is None or timeout_sec < 0 else round(timeout_sec * 1e9))
        if not self._context.ok():
            raise ExternalShutdownException()
        ready_waitables = [w for w in self._waitables if w.is_ready(ws)]
        timers = ws.get_ready_entities("timer")
        subs = ws.get_ready_entities("subscription")
        guards = ws.get_ready_entities("guard_condition")
        clients = ws.get_ready_entities("client")
        services = ws.get_ready_entities("service")
        for w in ready_waitables:
            data = w.take_data()
            _run(w.execute(data))
        if timers:
            for h, t in self._timers:
                if h.pointer in timers and h.is_timer_ready():
                    h.call_timer()
                    t.callback()
        if subs:
            for h, s in self._subs:
                if h.pointer in subs:
                    got = h.take_message(s.msg_type, s.raw)
                    if got is not None:
                        if s._callback_type is _MESSAGE_ONLY:
                            s.callback(got[0])
                        else:
                            s.callback(*got)
        if guards:
            for h, g in self._guards:
                if h.pointer in guards and g.callback is not None:
                    g.callback()
        if clients:
            for h, c in self._clients:
                if h.pointer in clients:
                    header, response = h.take_response(c.srv_type.Response)
                    if header is None:
                        continue
                    try:
                        future = c.get_pending_request(header.request_id.sequence_number)
                    except KeyError:  # the request was cancelled
                        continue
                    future.set_result(response)
        if services:
            for h, s in self._services:
                if h.pointer in services:
                    request, header = h.service_take_request(s.srv_type.Request)
                    if header is None:
                        continue
                    response = s.callback(request, s.srv_type.Response())
                    s.send_response(response, header)


#: the executor of a high-rate node: :class:`LeanExecutor` under a real rclpy, rclpy's
#: SingleThreadedExecutor where rclpy has no rcl wait set (the tests' stand-in, whose
#: executor runs the simulated clock)
HIGH_RATE_EXECUTOR: Any = SingleThreadedExecutor if _rclpy is None else LeanExecutor
