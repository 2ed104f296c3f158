"""The ROS 2 Jazzy typestore, QoS profiles and message definitions of a bag.

:func:`jazzy_typestore` is the one typestore the package writes with; :func:`make_qos`
builds the offered QoS profile of a topic; :func:`_definition_ok`, :func:`_rihs01` and
:func:`_deserializers` check and use the definitions a bag stores (as rosbags' AnyReader
does).
"""

from __future__ import annotations

import functools
import logging
from typing import Any, Iterable, Mapping

from lpv_sysid.errors import BagError
from lpv_sysid.io.bag.records import _Source

LOG = logging.getLogger(__name__)


@functools.lru_cache(maxsize=1)
def jazzy_typestore() -> Any:
    """The rosbags ROS 2 Jazzy typestore (built once; its classes are shared)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


# ---------------------------------------------------------------------------- QoS
DEFAULT_QOS = {
    "history": "keep_last",
    "depth": 10,
    "reliability": "reliable",
    "durability": "volatile",
    "liveliness": "automatic",
}


def make_qos(profile: Mapping | None = None) -> Any:
    """A ``rosbags.interfaces.Qos`` from a dict such as ``{"reliability": "best_effort",
    "depth": 5}``; missing keys take :data:`DEFAULT_QOS` (deadline, lifespan and lease
    0 = RMW default)."""
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    p = dict(DEFAULT_QOS)
    if profile:
        unknown = set(profile) - set(DEFAULT_QOS)
        if unknown:
            raise BagError(f"qos: unknown key(s) {sorted(unknown)}; known: {sorted(DEFAULT_QOS)}")
        p.update(profile)

    def enum(cls, key):
        try:
            return cls[str(p[key]).upper()]
        except KeyError:
            raise BagError(
                f"qos.{key}: unknown value {p[key]!r}; expected one of "
                f"{[m.name.lower() for m in cls]}"
            ) from None

    depth = p["depth"]
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
        raise BagError(f"qos.depth: expected a non-negative integer, got {depth!r}")
    zero = QosTime(0, 0)
    return Qos(
        enum(QosHistory, "history"),
        depth,
        enum(QosReliability, "reliability"),
        enum(QosDurability, "durability"),
        zero,
        zero,
        enum(QosLiveliness, "liveliness"),
        zero,
        False,
    )


@functools.lru_cache(maxsize=256)
def _definition_ok(msgtype: str, text: str, digest: str) -> bool:
    """AnyReader's check of a stored definition, cached: the ros2msg text parses and, when
    the bag stores a RIHS01 type hash, hashes to it."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(text, msgtype))
    return not digest or store.hash_rihs01(msgtype) == digest


def _deserializers(sources: Iterable[_Source]) -> dict[str, Any]:
    """msgtype -> typestore: the Jazzy store when the bag's definition equals Jazzy's (or
    the bag has none), else a store built from the definitions stored in the bag."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    jazzy = jazzy_typestore()
    out: dict[str, Any] = {}
    custom = None
    for src in sources:
        for msgtype in set(src.types.values()):
            text = src.msgdefs.get(msgtype)
            if msgtype in jazzy.types and (
                not text or jazzy.generate_msgdef(msgtype, ros_version=2)[0] == text
            ):
                out[msgtype] = jazzy
            elif text:
                if custom is None:
                    custom = get_typestore(Stores.EMPTY)
                try:
                    custom.register(get_types_from_msg(text, msgtype))
                    out[msgtype] = custom
                except Exception as exc:  # noqa: BLE001
                    LOG.warning("definition of %s unusable: %s", msgtype, exc)
    return out


def _rihs01(msgtype: str, encoding: str, text: str) -> str:
    """RIHS01 hash of a stored definition ('' when it cannot be computed)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    jazzy = jazzy_typestore()
    try:
        if msgtype in jazzy.types and jazzy.generate_msgdef(msgtype, ros_version=2)[0] == text:
            return jazzy.hash_rihs01(msgtype)
        if encoding == "ros2msg" and text:
            store = get_typestore(Stores.EMPTY)
            store.register(get_types_from_msg(text, msgtype))
            return store.hash_rihs01(msgtype)
    except Exception:  # noqa: BLE001 - a definition rosbags cannot parse has no hash
        pass
    return ""
