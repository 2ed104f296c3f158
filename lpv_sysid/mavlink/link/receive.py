"""The receive side of the MAVLink link: parsing, counters of what was received and rejected,
and the target autopilot's HEARTBEAT."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

from lpv_sysid.mavlink.link.config import (
    MAV_AUTOPILOT_INVALID,
    MAV_TYPE_GCS,
    MAV_TYPE_ONBOARD_CONTROLLER,
    MSG_HEARTBEAT,
    LinkConfig,
)
from lpv_sysid.mavlink.link.fast_decode import FastDecoder

log = logging.getLogger(__name__)


@dataclass
class LinkStats:
    """Counters of what the link received and rejected."""

    rx_bytes: int = 0
    rx_datagrams: int = 0
    rx_messages: int = 0
    tx_messages: int = 0
    bad_data: int = 0
    bad_prefix: int = 0
    bad_crc: int = 0
    bad_length: int = 0
    bad_signature: int = 0
    bad_other: int = 0
    unknown_msgid: int = 0
    truncated: int = 0
    seq_lost: int = 0
    reconnects: int = 0
    link_losses: int = 0
    io_errors: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class LinkEvent:
    """A change of link health (for the ``status`` topic)."""

    t: float
    kind: str  # "link_up" | "link_lost" | "reconnect" | "io_error" | "ambiguous_target"
    detail: str = ""


class LinkReceiver:
    """The receive side of :class:`lpv_sysid.mavlink.link.MavlinkLink`: parses received bytes
    (:class:`~lpv_sysid.mavlink.link.fast_decode.FastDecoder` for the hot telemetry, pymavlink
    for the rest), counts what is received and rejected in :class:`LinkStats`, and follows the
    target autopilot's HEARTBEAT (learns the target, raises ``link_up``)."""

    def __init__(self, config: LinkConfig, device: str, mod: Any) -> None:
        self.config = config
        self.stats = LinkStats()
        self._device = device
        self._mod = mod
        self.codec: Any = None
        self.target_system = config.target_system
        self.target_component = config.target_component
        self.last_heartbeat: Any = None  # last HEARTBEAT message of the target
        self.last_heartbeat_t: float | None = None
        self._up = False
        self._next_stream_req = 0.0
        self._counts: dict[int, int] = {}
        self._last_rx = -float("inf")
        self._requested_once = False
        self._last_seq: dict[tuple[int, int], int] = {}
        self._events: list[LinkEvent] = []
        self._fast: FastDecoder | None = None
        self._no_fast: Any = None  # a codec FastDecoder could not be built for
        #: autopilot system ids heard (target_system 0 locks only while there is one)
        self.autopilots_heard: set[int] = set()
        self.ambiguous_target = False  # target_system 0 and more than one autopilot heard

    def feed(self, data: bytes, now: float, out: list[Any] | None = None) -> list[Any]:
        """Parse one datagram / chunk of bytes; append decoded messages to ``out``."""
        out = [] if out is None else out
        st = self.stats
        self._last_rx = now
        st.rx_bytes += len(data)
        st.rx_datagrams += 1
        codec = self.codec
        fast = self._fast_decoder()
        if fast is not None and codec.buf_len() == 0:
            # whole packets of the hot ids: struct decode, CRC checked (FastDecoder); the
            # rest of the datagram, if any, goes through pymavlink
            if not isinstance(data, bytes):
                data = bytes(data)
            pos, got, lost, beats = fast.decode(data, out, self._counts, self._last_seq)
            if got:
                codec.total_bytes_received += pos
                codec.total_packets_received += got
                st.rx_messages += got
                st.seq_lost += lost
                for m in beats:
                    self._on_heartbeat(m, now)
            if pos >= len(data):
                return out
            data = data[pos:]
        msgs = codec.parse_buffer(data) or []
        bad_type = self._mod.MAVLINK_MSG_ID_BAD_DATA
        unknown_type = self._mod.MAVLink_unknown
        for m in msgs:
            mid = m.get_msgId()
            if mid == bad_type:
                self._count_bad(m)
                continue
            if isinstance(m, unknown_type):
                st.unknown_msgid += 1
                continue
            st.rx_messages += 1
            self._track_seq(m)
            if mid == MSG_HEARTBEAT:
                self._on_heartbeat(m, now)
            out.append(m)
        if self._is_datagram() and self.codec.buf_len() > 0:
            # a UDP datagram carries whole packets: the rest is a truncated packet
            st.truncated += 1
            self._reset_parser()
        return out

    def _fast_decoder(self) -> "FastDecoder | None":
        """The codec's :class:`FastDecoder`, or None when pymavlink must parse everything:
        signing configured (signatures, unsigned-message policy), a parser callback, CRC
        checks disabled in pymavlink, or a codec the decoder was not built for."""
        codec = self.codec
        if (
            codec is None
            or codec.signing.secret_key is not None
            or codec.callback is not None
            or getattr(self._mod, "MAVLINK_IGNORE_CRC", False)
        ):
            return None
        fd = self._fast
        if fd is None or fd.codec is not codec:
            if self._no_fast is codec:
                return None
            try:
                fd = self._fast = FastDecoder(codec, self._mod)
            except Exception as exc:  # noqa: BLE001 - pymavlink parses everything then
                log.debug("fast MAVLink decode unavailable: %s", exc)
                self._fast = None
                self._no_fast = codec
                return None
        return fd

    def from_autopilot(self, m: Any) -> bool:
        """The one check of MAVLink evidence (mode, arming, COMMAND_ACK, HOME_POSITION,
        telemetry): ``m`` comes from the target autopilot component (``target_system``,
        ``target_component``; MAV_COMP_ID_AUTOPILOT1 by default). A HEARTBEAT of another
        component of the vehicle's system (a companion, a camera, a spoofer using the
        vehicle's id) is no evidence of the autopilot's mode; an ambiguous target (see
        :meth:`_on_heartbeat`) is none at all."""
        return (
            not self.ambiguous_target
            and self.target_system != 0
            and m.get_srcSystem() == self.target_system
            and m.get_srcComponent() == self.target_component
        )

    def _on_heartbeat(self, m: Any, now: float) -> None:
        """Autopilot HEARTBEATs of the target component only. ``target_system: 0`` learns the
        system id of the first one, but only while a single autopilot is heard: a second
        autopilot system id on the link makes the target ambiguous (a foreign autopilot may
        have been heard first): an ``ambiguous_target`` event, and the link is down (link
        lost: the offboard machine's link-loss path) and stays down; name the vehicle with an
        explicit ``target_system``."""
        if m.autopilot == MAV_AUTOPILOT_INVALID or m.type in (
            MAV_TYPE_GCS,
            MAV_TYPE_ONBOARD_CONTROLLER,
        ):
            return
        src = m.get_srcSystem()
        if m.get_srcComponent() != self.target_component:
            return
        if self.config.target_system == 0:
            self.autopilots_heard.add(src)
            if len(self.autopilots_heard) > 1:
                if not self.ambiguous_target:
                    self.ambiguous_target = True  # link_up() is False from now on
                    ids = sorted(self.autopilots_heard)
                    self._events.append(
                        LinkEvent(
                            now,
                            "ambiguous_target",
                            f"autopilots of systems {ids} heard with link.target_system 0: "
                            "refusing to pick one; set link.target_system explicitly",
                        )
                    )
                return
            if self.target_system == 0:
                self.target_system = src
        if src != self.target_system:
            return
        self.last_heartbeat = m
        self.last_heartbeat_t = now
        if not self._up:
            self._up = True
            self._requested_once = False
            self._next_stream_req = now
            self._events.append(LinkEvent(now, "link_up", f"system {src} autopilot {m.autopilot}"))

    def _track_seq(self, m: Any) -> None:
        mid = m.get_msgId()
        self._counts[mid] = self._counts.get(mid, 0) + 1
        key = (m.get_srcSystem(), m.get_srcComponent())
        seq = m.get_seq()
        last = self._last_seq.get(key)
        if last is not None:
            gap = (seq - last - 1) % 256
            if gap < 128:  # larger jumps are restarts, not losses
                self.stats.seq_lost += gap
        self._last_seq[key] = seq

    def _count_bad(self, m: Any) -> None:
        st = self.stats
        st.bad_data += 1
        reason = str(getattr(m, "reason", "")).lower()
        if "prefix" in reason:
            st.bad_prefix += 1
        elif "crc" in reason:
            st.bad_crc += 1
        elif "signature" in reason:
            st.bad_signature += 1
        elif "length" in reason or "unpack" in reason:
            st.bad_length += 1
        else:
            st.bad_other += 1

    def _is_datagram(self) -> bool:
        return self._device.startswith("udp")

    def _reset_parser(self) -> None:
        c = self.codec
        c.buf = bytearray()
        c.buf_index = 0
        c.expected_length = self._mod.HEADER_LEN_V1 + 2
