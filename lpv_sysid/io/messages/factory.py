"""Message construction for both backends (:class:`MsgFactory`: rosbags dataclasses for CI
and bag files, rclpy messages onboard) and the error every builder and parser raises
(:class:`MessageError`)."""

from __future__ import annotations

import array
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from lpv_sysid.errors import ConfigError


class MessageError(ConfigError, ValueError):
    """A message cannot be built or parsed; the text names the field and the problem.
    ``row``: the index of the offending message for the parsers of many messages."""

    def __init__(self, message: str, row: int | None = None):
        super().__init__(message)
        self.row = row


def _float_list(values) -> list[float]:
    return [float(v) for v in values]


@dataclass(frozen=True)
class MsgFactory:
    """Message construction by type name ``pkg/msg/Name``.

    ``lookup`` returns the class; ``float_seq`` adapts an unbounded ``float64[]`` field,
    ``float_array`` a fixed-size ``float64[N]`` field and ``byte`` a ``byte`` field to
    what the backend accepts. Use :meth:`rosbags` or :meth:`rclpy`.
    """

    name: str
    lookup: Callable[[str], type]
    float_seq: Callable[[Any], Any]
    float_array: Callable[[Any], Any]
    byte: Callable[[int], Any]
    typestore: Any = None
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def rosbags(cls, typestore=None) -> "MsgFactory":
        """rosbags dataclasses from the ROS 2 Jazzy typestore (serialisable to CDR)."""
        if typestore is None:
            from rosbags.typesys import Stores, get_typestore

            typestore = get_typestore(Stores.ROS2_JAZZY)
        types = typestore.types

        def lookup(typename: str) -> type:
            try:
                return types[typename]
            except KeyError:
                raise MessageError(
                    f"unknown message type {typename!r} (not in the rosbags ROS2_JAZZY typestore)"
                ) from None

        def f64(values):
            return np.array(values, dtype=np.float64).reshape(-1)

        return cls("rosbags", lookup, f64, f64, int, typestore)

    @classmethod
    def rclpy(cls) -> "MsgFactory":
        """rclpy message classes via ``rosidl_runtime_py.utilities.get_message``; the import
        happens only here, so cores never pull in ROS."""
        try:
            from rosidl_runtime_py.utilities import get_message
        except ImportError as exc:
            raise ConfigError(
                f"MsgFactory.rclpy(): rosidl_runtime_py is not available ({exc}); "
                "source a ROS 2 Jazzy installation"
            ) from None

        def lookup(typename: str) -> type:
            try:
                return get_message(typename)
            except (ValueError, AttributeError, ImportError) as exc:
                raise MessageError(f"unknown message type {typename!r}: {exc}") from None

        def f64_fixed(values):
            return np.array(values, dtype=np.float64).reshape(-1)

        def f64_seq(values):
            return array.array("d", _float_list(np.asarray(values, dtype=float).reshape(-1)))

        return cls("rclpy", lookup, f64_seq, f64_fixed, lambda v: bytes([int(v)]))

    def get(self, typename: str) -> type:
        cls = self._cache.get(typename)
        if cls is None:
            cls = self.lookup(typename)
            self._cache[typename] = cls
        return cls

    def __call__(self, typename: str, **fields):
        return self.get(typename)(**fields)
