"""Stand-in for ``rclpy.context.Context``: also holds the in-process graph and sim clock."""

import threading

from rclpy._params_file import parse_ros_args

# Simulated clock origin: 2024-01-01T00:00:00Z, so stamps look like system time.
_EPOCH_NS = 1_704_067_200 * 10**9


class Context:
    def __init__(self):
        self._lock = threading.RLock()
        self._initialized = False
        self._shut = False
        self._callbacks = []
        self._domain_id = 0
        self._argv = []
        self._global_ros_args = ([], [], [])
        # stand-in state
        self._standin_now_ns = _EPOCH_NS
        self._standin_shutdown_at_ns = None
        self._standin_nodes = []

    def init(self, args=None, *, initialize_logging=True, domain_id=None):
        with self._lock:
            if self._initialized:
                raise RuntimeError("Context.init() must only be called once")
            self._global_ros_args = parse_ros_args(args)
            self._argv = list(args or [])
            self._domain_id = 0 if domain_id is None else int(domain_id)
            self._initialized = True
            self._shut = False

    def ok(self):
        return self._initialized and not self._shut

    def _check_ok(self):
        if not self.ok():
            from rclpy.exceptions import NotInitializedException

            raise NotInitializedException()

    def shutdown(self):
        with self._lock:
            if not self.ok():
                from rclpy._params_file import RCLError

                raise RCLError(
                    "failed to shutdown: rcl_shutdown already called on the given context"
                )
            self._shut = True
            for cb in list(self._callbacks):
                cb()
            self._callbacks.clear()

    def try_shutdown(self):
        with self._lock:
            if self.ok():
                self.shutdown()

    def on_shutdown(self, callback):
        if not callable(callback):
            raise TypeError("callback should be a callable, got {}".format(type(callback)))
        self._callbacks.append(callback)

    def get_domain_id(self):
        return self._domain_id

    def __enter__(self):
        self.init()
        return self

    def __exit__(self, *exc):
        self.try_shutdown()

    # -- stand-in graph --------------------------------------------------------------
    def _standin_entities(self, attr):
        for node in self._standin_nodes:
            yield from getattr(node, attr)
