"""Stand-in for ``rclpy.task.Future``."""


class Future:
    def __init__(self, *, executor=None):
        self._state = "pending"
        self._result = None
        self._exception = None
        self._callbacks = []

    def cancel(self):
        if self._state == "pending":
            self._state = "cancelled"
            self._run_callbacks()

    def cancelled(self):
        return self._state == "cancelled"

    def done(self):
        return self._state != "pending"

    def result(self):
        if self._exception is not None:
            raise self._exception
        return self._result

    def exception(self):
        return self._exception

    def set_result(self, result):
        self._result = result
        self._state = "finished"
        self._run_callbacks()

    def set_exception(self, exception):
        self._exception = exception
        self._state = "finished"
        self._run_callbacks()

    def add_done_callback(self, callback):
        if self.done():
            callback(self)
        else:
            self._callbacks.append(callback)

    def _run_callbacks(self):
        cbs, self._callbacks = self._callbacks, []
        for cb in cbs:
            cb(self)
