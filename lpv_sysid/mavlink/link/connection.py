"""The MAVLink connection (:class:`MavlinkLink`) over UDP, TCP or serial; the method is the
:mod:`lpv_sysid.mavlink.link` docstring."""

from __future__ import annotations

import logging
import math
from typing import Any, Callable

from lpv_sysid.errors import LpvSysidError
from lpv_sysid.mavlink import codec
from lpv_sysid.mavlink.link.config import (
    MAV_AUTOPILOT_INVALID,
    MAV_CMD_SET_MESSAGE_INTERVAL,
    MAV_STATE_ACTIVE,
    LinkConfig,
    load_signing_key,
)
from lpv_sysid.mavlink.link.receive import LinkEvent, LinkReceiver
from lpv_sysid.mavlink.link.url import parse_url, warn_if_all_interfaces

log = logging.getLogger(__name__)


class MavlinkLink(LinkReceiver):
    """A polled MAVLink 2 connection (see module docstring).

    ``connection_factory(device, baud, source_system, source_component)`` may be injected
    (tests); by default ``mavutil.mavlink_connection`` is used.
    """

    def __init__(
        self, config: LinkConfig, connection_factory: Callable[..., Any] | None = None
    ) -> None:
        config.validate()
        device, self._baud = parse_url(config.url, config.baud)
        self._key = load_signing_key(config.signing_key_file) if config.signing_key_file else None
        super().__init__(config, device, codec.dialect_module(config.dialect))
        self._factory = connection_factory or _mavutil_connection
        self.conn: Any = None
        self._next_hb = 0.0
        self._last_reopen = 0.0
        self._stream_ids = [(self._msg_id(n), r) for n, r in config.streams]

    # ------------------------------------------------------------------ lifecycle
    def open(self, now: float = 0.0) -> None:
        """Open the transport (raises :class:`LpvSysidError` if the device cannot be opened)."""
        try:
            self.conn = self._factory(
                self._device, self._baud, self.config.source_system, self.config.source_component
            )
        except ImportError as exc:
            raise LpvSysidError(
                f"cannot open MAVLink connection {self.config.url!r}: {exc} "
                "(serial links need pyserial, ROS package python3-serial)"
            ) from None
        except (OSError, ValueError) as exc:
            raise LpvSysidError(
                f"cannot open MAVLink connection {self.config.url!r}: {exc}"
            ) from None
        if self._device.startswith(("udpin:", "tcpin:")):
            warn_if_all_interfaces(f"MAVLink link {self.config.url!r}", self._device.split(":")[1])
        self.codec = codec.make_codec(
            self.conn, self.config.source_system, self.config.source_component, self.config.dialect
        )
        if self._key is not None:
            codec.setup_signing(
                self.codec, self._key, self.config.signing_link_id, self.config.allow_unsigned
            )
        # the connection object keeps its own (mavutil) parser; ours replaces it
        self.conn.mav = self.codec
        self.conn.WIRE_PROTOCOL_VERSION = "2.0"
        self.conn.first_byte = False
        self._last_reopen = now

    def close(self) -> None:
        if self.conn is not None:
            try:
                self.conn.close()
            except OSError:
                pass
            self.conn = None

    @property
    def dialect_module(self) -> Any:
        """The pymavlink dialect module (message ids, enums)."""
        return self._mod

    @property
    def is_open(self) -> bool:
        return self.conn is not None

    def link_up(self, now: float) -> bool:
        return (
            not self.ambiguous_target
            and self.last_heartbeat_t is not None
            and now - self.last_heartbeat_t <= self.config.link_timeout
        )

    # ---------------------------------------------------------------------- I/O
    def poll(self, now: float, max_reads: int = 1000) -> list[Any]:
        """Read everything available (at most ``max_reads`` datagrams); return the messages.

        Bad data is counted, not returned. Link events are collected for :meth:`events`.
        """
        out: list[Any] = []
        if self.conn is None:
            return out
        for _ in range(max_reads):
            try:
                data = self._read()
            except OSError as exc:
                self._io_failure(now, f"read failed: {exc}")
                break
            if data is None:
                self._io_failure(now, "peer closed the connection")
                break
            if not data:
                break
            self.feed(data, now, out)
        return out

    def _read(self) -> bytes | None:
        """One read; b"" when nothing is pending, None on end-of-stream (TCP peer gone)."""
        if self._device.startswith("tcp:"):
            # read the socket directly: mavutil's TCP client prints on EOF and returns b"",
            # which would hide the disconnection
            sock = getattr(self.conn, "port", None)
            if sock is None:
                raise OSError("TCP socket closed")
            try:
                data = sock.recv(65535)
            except (BlockingIOError, InterruptedError):
                return b""
            return data if data else None
        return self.conn.recv(65535)

    def _io_failure(self, now: float, detail: str) -> None:
        self.stats.io_errors += 1
        self._events.append(LinkEvent(now, "io_error", detail))
        if not self._is_datagram():
            # serial/TCP: drop the transport; step() reopens it every reconnect_period
            self.close()
            self._last_reopen = now

    def wait_readable(self, timeout: float) -> bool:
        """Block up to ``timeout`` s until data is available (select); lets a shell thread
        react to telemetry at once instead of at the next timer tick."""
        import select

        if self.conn is None:
            return False
        sock = getattr(self.conn, "port", None)
        fd = (
            sock.fileno()
            if sock is not None and hasattr(sock, "fileno")
            else getattr(self.conn, "fd", None)
        )
        if fd is None:
            return True
        try:
            r, _, _ = select.select([fd], [], [], max(timeout, 0.0))
        except (OSError, ValueError):
            return False
        return bool(r)

    def send(self, msg: Any) -> None:
        if self.conn is None:
            return
        try:
            self.codec.send(msg)
            self.stats.tx_messages += 1
        except OSError as exc:
            self.stats.io_errors += 1
            log.debug("send failed: %s", exc)

    def step(self, now: float) -> None:
        """Periodic work: heartbeat, stream requests, link-loss detection, reconnect."""
        up = self.link_up(now)
        if self._up and not up:
            self._up = False
            self.stats.link_losses += 1
            last = self.last_heartbeat_t
            silent = now - last if last is not None else math.inf
            self._events.append(LinkEvent(now, "link_lost", f"no HEARTBEAT for {silent:.2f} s"))
        if self.conn is None:
            if now - self._last_reopen >= self.config.reconnect_period:
                self._reopen(now)
            return
        if now >= self._next_hb:
            self._next_hb = now + self.config.heartbeat_period
            self.send(
                self.codec.heartbeat_encode(
                    self.config.mav_type, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE
                )
            )
        if up and now >= self._next_stream_req:
            self._next_stream_req = now + self.config.stream_request_period
            self.request_streams(only_missing=self._requested_once)
            self._requested_once = True
        if not up and self.last_heartbeat_t is not None and self._device_reopens():
            # serial/TCP silent (no bytes at all) since the last (re)open: reopen the device
            quiet = now - max(self._last_reopen, self._last_rx)
            if quiet >= max(self.config.reconnect_period, self.config.link_timeout):
                self._reopen(now)

    def events(self) -> list[LinkEvent]:
        """Link events since the last call."""
        ev, self._events = self._events, []
        return ev

    def request_streams(self, only_missing: bool = False) -> int:
        """Send SET_MESSAGE_INTERVAL for the configured streams; returns how many were sent.

        ``only_missing``: only streams that arrived at less than half the requested rate
        since the previous call (PX4 may drop a request or reset intervals on reboot).
        """
        n = 0
        counts, self._counts = self._counts, {}
        window = self.config.stream_request_period
        for mid, rate in self._stream_ids:
            if only_missing and (rate == 0 or counts.get(mid, 0) >= 0.5 * rate * window):
                continue
            interval_us = -1 if rate == 0 else int(round(1e6 / rate))
            self.command_long(MAV_CMD_SET_MESSAGE_INTERVAL, float(mid), float(interval_us))
            n += 1
        return n

    def command_long(self, command: int, *params: float, confirmation: int = 0) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(
            self.codec.command_long_encode(
                self.target_system or 1, self.target_component, command, confirmation, *p[:7]
            )
        )

    # ---------------------------------------------------------------- internals
    def _msg_id(self, name: str) -> int:
        if name == "ESC_STATUS":
            return codec.MAVLINK_MSG_ID_ESC_STATUS
        return int(getattr(self._mod, f"MAVLINK_MSG_ID_{name}"))

    def _device_reopens(self) -> bool:
        # UDP sockets stay valid when the peer goes away; serial/TCP are reopened.
        return not self._is_datagram()

    def _reopen(self, now: float) -> None:
        self._last_reopen = now
        self.close()
        try:
            self.open(now)
        except LpvSysidError as exc:
            self.stats.io_errors += 1
            self._events.append(LinkEvent(now, "io_error", str(exc)))
            return
        self.stats.reconnects += 1
        self._events.append(LinkEvent(now, "reconnect", self.config.url))


def _mavutil_connection(device: str, baud: int, source_system: int, source_component: int) -> Any:
    from pymavlink import mavutil  # imported lazily: it loads a dialect on import

    # retries=0: one connection attempt (no blocking sleeps); MavlinkLink.step() retries
    return mavutil.mavlink_connection(
        device,
        baud=baud,
        source_system=source_system,
        source_component=source_component,
        autoreconnect=False,
        robust_parsing=True,
        retries=0,
    )


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port that is free right now (tests and benchmarks)."""
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind((host, 0))
        return int(s.getsockname()[1])
    finally:
        s.close()
