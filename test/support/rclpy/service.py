"""Stand-in for ``rclpy.service.Service``."""

import collections

import _rosmsg_standin as _msgs


class Service:
    def __init__(self, node, srv_type, srv_name, callback, callback_group, qos_profile):
        self._node = node
        self.srv_type = srv_type
        self._srv_name = srv_name
        self.callback = callback
        self.callback_group = callback_group
        self.qos_profile = qos_profile
        self._requests = collections.deque()

    @property
    def service_name(self):
        return self._srv_name

    @property
    def handle(self):
        return self

    def _standin_ready(self):
        return bool(self._requests)

    def _standin_execute(self):
        data, client, seq = self._requests.popleft()
        request = _msgs.deserialize(data, self.srv_type.Request)
        response = self.callback(request, self.srv_type.Response())
        self.send_response(response, (client, seq))

    def send_response(self, response, header):
        if not isinstance(response, self.srv_type.Response):
            raise TypeError(f"Expected {self.srv_type.Response}, got {type(response)}")
        client, seq = header
        client._standin_responses.append((seq, _msgs.serialize(response)))

    def destroy(self):
        self._node.destroy_service(self)
