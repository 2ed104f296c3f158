"""Stand-in for ``rclpy.subscription.Subscription``: a KEEP_LAST/KEEP_ALL queue."""

import collections

import _rosmsg_standin as _msgs

from rclpy._standin_entity import TopicEndpoint
from rclpy.qos import HistoryPolicy


class Subscription(TopicEndpoint):
    def __init__(
        self,
        node,
        msg_type,
        topic,
        callback,
        callback_group,
        qos_profile,
        raw=False,
        event_callbacks=None,
    ):
        super().__init__(node, msg_type, topic, qos_profile, event_callbacks)
        self.callback = callback
        self.callback_group = callback_group
        self.raw = raw
        depth = (
            None
            if qos_profile.history == HistoryPolicy.KEEP_ALL
            else max(int(qos_profile.depth), 1)
        )
        self._queue = collections.deque(maxlen=depth)
        self.standin_received = 0
        self.standin_dropped = 0

    def _standin_enqueue(self, data):
        if self._queue.maxlen is not None and len(self._queue) == self._queue.maxlen:
            self.standin_dropped += 1
        self._queue.append(data)
        self.standin_received += 1

    def _standin_ready(self):
        return bool(self._queue)

    def _standin_execute(self):
        data = self._queue.popleft()
        msg = data if self.raw else _msgs.deserialize(data, self.msg_type)
        self.callback(msg)

    def standin_lose(self, n):
        """Simulate ``n`` samples lost by the middleware (fires ``message_lost``)."""
        self.standin_lost = getattr(self, "standin_lost", 0) + n
        cbs = self.event_callbacks
        if cbs is not None and cbs.message_lost is not None:
            from rclpy.event_handler import QoSMessageLostInfo

            cbs.message_lost(
                QoSMessageLostInfo(total_count=self.standin_lost, total_count_change=n)
            )

    def destroy(self):
        self._node.destroy_subscription(self)
