"""Private bases of the stand-in's node entities (no rclpy equivalent).

In Jazzy rclpy, Publisher, Subscription, Client, Service and Timer each wrap their own rcl
handle; in the stand-in every entity is its own ``handle``, and the two kinds of
endpoint keep the same constructor fields, so those live here once.
"""


class Entity:
    @property
    def handle(self):
        return self


class TopicEndpoint(Entity):
    """Publisher / Subscription: owning node, message type, resolved topic, QoS, events."""

    def __init__(self, node, msg_type, topic, qos_profile, event_callbacks):
        self._node = node
        self.msg_type = msg_type
        self._topic = topic
        self.qos_profile = qos_profile
        self.event_callbacks = event_callbacks

    @property
    def topic_name(self):
        return self._topic


class ServiceEndpoint(Entity):
    """Client / Service: owning node, service type, resolved name, callback group, QoS."""

    def __init__(self, node, srv_type, srv_name, callback_group, qos_profile):
        self._node = node
        self.srv_type = srv_type
        self._srv_name = srv_name
        self.callback_group = callback_group
        self.qos_profile = qos_profile

    @property
    def service_name(self):
        return self._srv_name
