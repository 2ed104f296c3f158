"""Stand-in for ``rclpy.publisher.Publisher``: in-process delivery to matching subscriptions."""

import collections

import _rosmsg_standin as _msgs

from rclpy._standin_entity import TopicEndpoint
from rclpy.qos import DurabilityPolicy, QoSCompatibility, qos_check_compatible


class Publisher(TopicEndpoint):
    def __init__(self, node, msg_type, topic, qos_profile, event_callbacks=None):
        super().__init__(node, msg_type, topic, qos_profile, event_callbacks)
        self._destroyed = False
        keep = (
            qos_profile.depth if qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL else 0
        )
        self._latched = collections.deque(maxlen=keep or None) if keep else None
        self.standin_published = 0

    @property
    def topic(self):
        return self._topic

    def get_subscription_count(self):
        return sum(
            1
            for s in self._node.context._standin_entities("subscriptions")
            if s.topic_name == self._topic
        )

    def publish(self, msg):
        if self._destroyed:
            from rclpy.exceptions import InvalidHandle

            raise InvalidHandle("cannot use Destroyable because destruction was requested")
        if not self._node.context.ok():
            # as rclpy_pybind11 once the context is shut down (e.g. by rclpy's SIGINT handler)
            from rclpy._params_file import RCLError

            raise RCLError("Failed to publish: publisher's context is invalid")
        if isinstance(msg, (bytes, bytearray)):
            data = bytes(msg)
        elif isinstance(msg, self.msg_type):
            data = _msgs.serialize(msg)
        else:
            raise TypeError(f"Expected {self.msg_type}, got {type(msg)}")
        self.standin_published += 1
        if self._latched is not None:
            self._latched.append(data)
        for sub in self._node.context._standin_entities("subscriptions"):
            if sub.topic_name == self._topic and self._compatible(sub):
                sub._standin_enqueue(data)

    def _compatible(self, sub):
        if sub.msg_type._lpv_typename != self.msg_type._lpv_typename:
            return False
        comp, _ = qos_check_compatible(self.qos_profile, sub.qos_profile)
        return comp != QoSCompatibility.ERROR

    def wait_for_all_acked(self, timeout=None):
        return True

    def assert_liveliness(self):
        pass

    def destroy(self):
        self._destroyed = True
