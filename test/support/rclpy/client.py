"""Stand-in for ``rclpy.client.Client``."""

import collections

import _rosmsg_standin as _msgs

from rclpy._standin_entity import ServiceEndpoint
from rclpy.task import Future


class Client(ServiceEndpoint):
    def __init__(self, node, srv_type, srv_name, qos_profile, callback_group):
        super().__init__(node, srv_type, srv_name, callback_group, qos_profile)
        self._seq = 0
        self._pending = {}
        self._standin_responses = collections.deque()

    def _service(self):
        for s in self._node.context._standin_entities("services"):
            if (
                s.service_name == self._srv_name
                and s.srv_type._lpv_typename == self.srv_type._lpv_typename
            ):
                return s
        return None

    def service_is_ready(self):
        return self._service() is not None

    def wait_for_service(self, timeout_sec=None):
        if self.service_is_ready():
            return True
        if timeout_sec is None:
            raise RuntimeError(
                "stand-in: wait_for_service would block forever "
                f"(no server for '{self._srv_name}')"
            )
        self._node.context._standin_now_ns += int(timeout_sec * 1e9)
        return self.service_is_ready()

    def call_async(self, request):
        if not isinstance(request, self.srv_type.Request):
            raise TypeError(f"Expected {self.srv_type.Request}, got {type(request)}")
        self._seq += 1
        future = Future()
        self._pending[self._seq] = future
        srv = self._service()
        if srv is not None:
            srv._requests.append((_msgs.serialize(request), self, self._seq))
        return future

    def call(self, request, timeout_sec=None):
        """Synchronous call: the stand-in runs the server's and this client's callbacks."""
        future = self.call_async(request)
        srv = self._service()
        if srv is None:
            raise RuntimeError(f"stand-in: no server for '{self._srv_name}'")
        while srv._standin_ready():
            srv._standin_execute()
        while self._standin_ready():
            self._standin_execute()
        return future.result()

    def _standin_ready(self):
        return bool(self._standin_responses)

    def _standin_execute(self):
        seq, data = self._standin_responses.popleft()
        future = self._pending.pop(seq, None)
        if future is not None and not future.cancelled():
            future.set_result(_msgs.deserialize(data, self.srv_type.Response))

    def remove_pending_request(self, future):
        for k, f in list(self._pending.items()):
            if f is future:
                del self._pending[k]

    def destroy(self):
        self._node.destroy_client(self)
