"""Stand-in for ``rclpy.service.Service``."""

import collections

import _rosmsg_standin as _msgs

from rclpy._standin_entity import ServiceEndpoint


class Service(ServiceEndpoint):
    def __init__(self, node, srv_type, srv_name, callback, callback_group, qos_profile):
        super().__init__(node, srv_type, srv_name, callback_group, qos_profile)
        self.callback = callback
        self._requests = collections.deque()

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
