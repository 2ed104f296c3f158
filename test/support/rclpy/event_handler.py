"""Stand-in for ``rclpy.event_handler`` (the QoS event callbacks the shells use).

The stand-in transport never loses a sample by itself; tests simulate middleware loss
with ``Subscription.standin_lose(n)``, which fires ``message_lost`` like a DDS reader.
"""

from dataclasses import dataclass


@dataclass
class QoSMessageLostInfo:
    total_count: int = 0
    total_count_change: int = 0


@dataclass
class QoSRequestedIncompatibleQoSInfo:
    total_count: int = 0
    total_count_change: int = 0
    last_policy_kind: int = 0


class SubscriptionEventCallbacks:
    def __init__(
        self,
        *,
        deadline=None,
        incompatible_qos=None,
        liveliness=None,
        message_lost=None,
        use_default_callbacks=True,
        incompatible_type=None,
        matched=None,
    ):
        self.deadline = deadline
        self.incompatible_qos = incompatible_qos
        self.liveliness = liveliness
        self.message_lost = message_lost
        self.use_default_callbacks = use_default_callbacks
        self.incompatible_type = incompatible_type
        self.matched = matched


class PublisherEventCallbacks:
    def __init__(
        self,
        *,
        deadline=None,
        liveliness=None,
        incompatible_qos=None,
        use_default_callbacks=True,
        incompatible_type=None,
        matched=None,
    ):
        self.deadline = deadline
        self.liveliness = liveliness
        self.incompatible_qos = incompatible_qos
        self.use_default_callbacks = use_default_callbacks
        self.incompatible_type = incompatible_type
        self.matched = matched
