"""Shared glue of the rclpy shells: topic table, QoS, parameter descriptors, base node, main().

Imported only by ``lpv_sysid/nodes/*`` (rclpy is imported here, never in the cores).
"""

from __future__ import annotations

import math

import rclpy
import rclpy.logging
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (QoSDurabilityPolicy, QoSHistoryPolicy, QoSProfile, QoSReliabilityPolicy,
                       qos_profile_sensor_data)

from lpv_sysid.errors import LpvSysidError
from lpv_sysid.io.messages import TYPES

NAMESPACE = "lpv_sysid"

# ARCHITECTURE.md Sec. 4 / DESIGN.md: topic (relative to /lpv_sysid) -> type
TOPIC_TYPES = dict(TYPES)
# high-rate measurement streams: best effort (a late sample is worthless); the rest
# (references, excitation, commands, status) reliable.
SENSOR_TOPICS = frozenset({"state", "rotor_speeds", "imu"})

QOS_SENSOR = qos_profile_sensor_data
QOS_RELIABLE = QoSProfile(history=QoSHistoryPolicy.KEEP_LAST, depth=10,
                          reliability=QoSReliabilityPolicy.RELIABLE,
                          durability=QoSDurabilityPolicy.VOLATILE)


def qos_for(topic: str) -> QoSProfile:
    return QOS_SENSOR if topic in SENSOR_TOPICS else QOS_RELIABLE


def double(description: str, lo: float, hi: float, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(
        type=Parameter.Type.DOUBLE.value, description=description, read_only=read_only,
        floating_point_range=[FloatingPointRange(from_value=float(lo), to_value=float(hi),
                                                 step=0.0)])


def integer(description: str, lo: int, hi: int) -> ParameterDescriptor:
    return ParameterDescriptor(
        type=Parameter.Type.INTEGER.value, description=description,
        integer_range=[IntegerRange(from_value=int(lo), to_value=int(hi), step=1)])


def typed(kind: Parameter.Type, description: str, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(type=kind.value, description=description, read_only=read_only)


def declare(node, table) -> dict:
    """Declare ``[(name, default, descriptor)]``; return ``{name: value}``.

    A ``Parameter.Type`` default declares a parameter without default (a list parameter
    whose natural default is empty: an empty list would be typed BYTE_ARRAY by rclpy);
    it reads as ``[]`` when not set from a parameter file.
    """
    values = {}
    for name, default, descriptor in table:
        p = node.declare_parameter(name, default, descriptor)
        if isinstance(default, Parameter.Type):
            p = node.get_parameter_or(name, Parameter(name, value=[]))
        values[name] = p.value
    return values


class ShellNode(Node):
    """Base of the node shells: ``node_name`` in ``/lpv_sysid`` unless a namespace is given
    (a ``__ns`` remap still wins), the module's parameter table declared into
    ``self.params`` (see :func:`declare`), and the node clock in seconds / nanoseconds."""

    #: at most one "rejected" warning per input topic in this period [s]
    REJECT_LOG_PERIOD_S = 1.0

    def __init__(self, node_name: str, parameters, **kwargs):
        kwargs.setdefault("namespace", NAMESPACE)
        super().__init__(node_name, **kwargs)
        self._rejected_logged_at: dict[str, float] = {}
        self.params = declare(self, parameters)

    def now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def now(self) -> float:
        return self.now_ns() * 1e-9

    def parse_input(self, topic: str, parse, msg):
        """``parse(msg)``; a bad message (LpvSysidError) is dropped with a warning naming
        ``topic`` (at most one per topic per :attr:`REJECT_LOG_PERIOD_S` of node time) and
        gives ``None``: one bad input never stops the node."""
        try:
            return parse(msg)
        except LpvSysidError as exc:
            # throttled per topic by hand: rclpy's throttle_duration_sec keys on the call
            # site, which is this one line for every topic of every shell
            now = self.now()
            if now - self._rejected_logged_at.get(topic, -math.inf) >= self.REJECT_LOG_PERIOD_S:
                self._rejected_logged_at[topic] = now
                self.get_logger().warning(f"{topic} rejected: {exc}")
            return None


def run(node_factory, args=None, name: str = NAMESPACE) -> int:
    """ros2/examples minimal-node main: init, spin, clean up on Ctrl-C or shutdown.

    Bad configuration (LpvSysidError, e.g. an invalid gains file) ends the node with one
    FATAL log line naming the problem and exit status 2.
    """
    rclpy.init(args=args)
    node = None
    try:
        node = node_factory()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except LpvSysidError as exc:
        rclpy.logging.get_logger(name).fatal(f"{name}: {exc}")
        return 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
