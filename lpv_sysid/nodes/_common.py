"""Shared glue of the rclpy shells: topic table, QoS, parameter descriptors, main().

Imported only by ``lpv_sysid/nodes/*`` (rclpy is imported here, never in the cores).
"""

from __future__ import annotations

import rclpy
import rclpy.logging
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException
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
