"""MAVLink 2 link to PX4 over UDP, TCP or serial (pymavlink ``mavutil`` transports).

The link is a polled object: the owner calls :meth:`MavlinkLink.poll` with its own
clock (``now`` in seconds, monotonic or simulated) and gets the decoded messages and
link events back. Nothing here blocks or starts threads, so the same code runs in the
rclpy shell's timer, in a lock-step simulation and in benchmarks.

Responsibilities
- transport: ``mavutil.mavlink_connection`` (``udpin:``, ``udpout:``, ``tcp:``, serial
  device), with MAVSDK-style URLs (``udp://:14540``, ``udpout://h:p``,
  ``serial:///dev/ttyACM0:921600``) translated;
- codec: MAVLink 2 (:func:`lpv_sysid.mavlink.codec.make_codec`), robust parsing; bad
  bytes, CRC errors, unknown ids, bad signatures and truncated UDP datagrams are counted
  in :class:`LinkStats`, never raised; the high-rate telemetry (:data:`FAST_MESSAGES`) is
  decoded by :class:`FastDecoder` (struct unpacking, X.25 CRC with CRC_EXTRA checked, the
  same message objects as pymavlink's), everything else and anything unusual by pymavlink;
- optional signing with a 32-byte secret key read from a file;
- HEARTBEAT at ``heartbeat_period`` (MAV_TYPE_ONBOARD_CONTROLLER);
- SET_MESSAGE_INTERVAL (MAV_CMD_SET_MESSAGE_INTERVAL, 511) for the telemetry streams,
  repeated until each stream is seen;
- evidence only from the target autopilot component (``MavlinkLink.from_autopilot``:
  ``target_system``/``target_component``); ``target_system: 0`` learns the id while a
  single autopilot is heard and refuses (``ambiguous_target``, link down) when two are;
- link loss (no HEARTBEAT from the target for ``link_timeout``) and reconnection
  (the transport is reopened every ``reconnect_period`` while the link is down).

Modules: this one (:class:`MavlinkLink`: transport, I/O, heartbeat, stream requests, link
health), :mod:`~lpv_sysid.mavlink.link.receive` (parsing, :class:`LinkStats`, the target's
HEARTBEAT), :mod:`~lpv_sysid.mavlink.link.fast_decode` (:class:`FastDecoder`),
:mod:`~lpv_sysid.mavlink.link.config` (:class:`LinkConfig`, signing key) and
:mod:`~lpv_sysid.mavlink.link.url` (:func:`parse_url`). Their public names are importable
from here as well.
"""

from __future__ import annotations

from lpv_sysid.mavlink.link.config import DEFAULT_STREAMS, LinkConfig, load_signing_key
from lpv_sysid.mavlink.link.connection import MavlinkLink, free_udp_port
from lpv_sysid.mavlink.link.fast_decode import FAST_MESSAGES, FastDecoder, x25_crc
from lpv_sysid.mavlink.link.receive import LinkEvent
from lpv_sysid.mavlink.link.url import parse_url, warn_if_all_interfaces

__all__ = [
    "DEFAULT_STREAMS",
    "FAST_MESSAGES",
    "FastDecoder",
    "LinkConfig",
    "LinkEvent",
    "MavlinkLink",
    "free_udp_port",
    "load_signing_key",
    "parse_url",
    "warn_if_all_interfaces",
    "x25_crc",
]
