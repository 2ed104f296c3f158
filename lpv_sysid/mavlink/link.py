"""MAVLink 2 link to PX4 over UDP, TCP or serial (pymavlink ``mavutil`` transports).

The link is a polled object: the owner calls :meth:`MavlinkLink.poll` with its own
clock (``now`` in seconds, monotonic or simulated) and gets the decoded messages and
link events back. Nothing here blocks or starts threads, so the same code runs in the
rclpy shell's timer, in a lock-step simulation and in benchmarks.

Responsibilities
- transport: ``mavutil.mavlink_connection`` (``udpin:``, ``udpout:``, ``tcp:``, serial
  device), with MAVSDK-style URLs (``udp://:14540``, ``udpout://h:p``,
  ``serial:///dev/ttyACM0:921600``) translated;
- codec: MAVLink 2 (:func:`lpv_sysid.mavlink.px4.make_codec`), robust parsing; bad
  bytes, CRC errors, unknown ids, bad signatures and truncated UDP datagrams are counted
  in :class:`LinkStats`, never raised; the high-rate telemetry (:data:`FAST_MESSAGES`) is
  decoded by :class:`FastDecoder` (struct unpacking, X.25 CRC with CRC_EXTRA checked, the
  same message objects as pymavlink's), everything else and anything unusual by pymavlink;
- optional signing with a 32-byte secret key read from a file;
- HEARTBEAT at ``heartbeat_period`` (MAV_TYPE_ONBOARD_CONTROLLER);
- SET_MESSAGE_INTERVAL (MAV_CMD_SET_MESSAGE_INTERVAL, 511) for the telemetry streams,
  repeated until each stream is seen;
- link loss (no HEARTBEAT from the target for ``link_timeout``) and reconnection
  (the transport is reopened every ``reconnect_period`` while the link is down).
"""

from __future__ import annotations

import binascii
import logging
import math
import struct
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from lpv_sysid.errors import ConfigError, LpvSysidError
from lpv_sysid.mavlink import px4
from lpv_sysid.config_fields import check_config_keys

log = logging.getLogger(__name__)

# MAVLink ids used below (common.xml); kept numeric so that no dialect global is needed.
MSG_HEARTBEAT = 0
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_TYPE_GCS = 6
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_AUTOPILOT_PX4 = 12
MAV_STATE_ACTIVE = 4

#: default telemetry streams [Hz] (message name -> rate); ids resolved from the dialect.
DEFAULT_STREAMS: tuple[tuple[str, float], ...] = (
    ("LOCAL_POSITION_NED", 50.0),
    ("ATTITUDE_QUATERNION", 100.0),
    ("HIGHRES_IMU", 100.0),
    ("ESC_STATUS", 50.0),
)


@dataclass(frozen=True)
class LinkConfig:
    """Link parameters (``config/mavlink_bridge.yaml`` section ``link``)."""

    url: str = "udpin:127.0.0.1:14540"
    baud: int = 921600
    source_system: int = 1
    source_component: int = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
    target_system: int = 0  # 0: learn from the first autopilot HEARTBEAT
    target_component: int = 1  # MAV_COMP_ID_AUTOPILOT1
    dialect: str = px4.DEFAULT_DIALECT
    heartbeat_period: float = 1.0
    link_timeout: float = 1.5
    reconnect_period: float = 2.0
    stream_request_period: float = 1.0
    streams: tuple[tuple[str, float], ...] = DEFAULT_STREAMS
    signing_key_file: str | None = None
    signing_link_id: int = 0
    allow_unsigned: bool = False
    mav_type: int = MAV_TYPE_ONBOARD_CONTROLLER

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "LinkConfig":
        check_config_keys(d, cls.__dataclass_fields__, "link")
        kw = dict(d)
        if "streams" in kw:
            s = kw["streams"]
            if not isinstance(s, Mapping):
                raise ConfigError("link.streams must be a mapping MESSAGE_NAME: rate_hz")
            kw["streams"] = tuple(
                (str(k), _positive(f"link.streams.{k}", v, allow_zero=True)) for k, v in s.items()
            )
        cfg = cls(**kw)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        if not isinstance(self.url, str) or not self.url:
            raise ConfigError("link.url must be a non-empty string")
        parse_url(self.url)
        for name in ("source_system", "target_system", "source_component", "target_component"):
            v = getattr(self, name)
            if not isinstance(v, int) or not 0 <= v <= 255:
                raise ConfigError(f"link.{name} must be an integer 0..255, got {v!r}")
        if self.source_system == 0:
            raise ConfigError("link.source_system must be 1..255")
        for name in (
            "heartbeat_period",
            "link_timeout",
            "reconnect_period",
            "stream_request_period",
        ):
            _positive(f"link.{name}", getattr(self, name))
        mod = px4.dialect_module(self.dialect)
        for name, rate in self.streams:
            if name != "ESC_STATUS" and not hasattr(mod, f"MAVLINK_MSG_ID_{name}"):
                raise ConfigError(f"link.streams: unknown MAVLink message {name!r}")
            _positive(f"link.streams.{name}", rate, allow_zero=True)


def _positive(name: str, v: Any, allow_zero: bool = False) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be a number, got {v!r}") from None
    if f != f or f in (float("inf"), float("-inf")) or f < 0 or (f == 0 and not allow_zero):
        raise ConfigError(
            f"{name} must be a finite {'non-negative' if allow_zero else 'positive'} number, got "
            f"{v!r}"
        )
    return f


def parse_url(url: str, baud: int = 921600) -> tuple[str, int]:
    """Translate a connection URL into ``(mavutil device string, baud)``.

    Accepted: ``udpin:H:P``, ``udpout:H:P``, ``udp:H:P`` (= udpin), ``tcp:H:P``,
    ``tcpin:H:P``, a serial device path (``/dev/ttyACM0`` or ``/dev/ttyACM0:57600``) and
    the MAVSDK forms ``udp://[H]:P``, ``udpin://[H]:P``, ``udpout://H:P``, ``tcp://H:P``,
    ``serial:///dev/ttyX[:baud]``.
    """
    if not isinstance(url, str) or not url.strip():
        raise ConfigError("connection URL is empty")
    u = url.strip()
    if "://" in u:
        scheme, rest = u.split("://", 1)
        scheme = scheme.lower()
        if scheme == "serial":
            dev, _, b = rest.partition(":")
            return dev, _baud(b, baud, url)
        host, sep, port = rest.rpartition(":")
        if not sep:
            raise ConfigError(f"connection URL {url!r} has no port")
        _port(port, url)
        if scheme in ("udp", "udpin"):
            return f"udpin:{host or '0.0.0.0'}:{port}", baud
        if scheme == "udpout":
            return f"udpout:{host or '127.0.0.1'}:{port}", baud
        if scheme in ("tcp", "tcpout"):
            return f"tcp:{host or '127.0.0.1'}:{port}", baud
        if scheme == "tcpin":
            return f"tcpin:{host or '0.0.0.0'}:{port}", baud
        raise ConfigError(f"connection URL {url!r}: unsupported scheme {scheme!r}")
    for prefix in ("udpin:", "udpout:", "udp:", "tcp:", "tcpin:"):
        if u.startswith(prefix):
            parts = u[len(prefix) :].split(":")
            if len(parts) != 2 or not parts[0]:
                raise ConfigError(f"connection URL {url!r}: expected {prefix}HOST:PORT")
            _port(parts[1], url)
            if prefix == "udp:":
                return "udpin:" + u[len(prefix) :], baud
            return u, baud
    if u.startswith("/dev/") or u.upper().startswith("COM"):
        dev, _, b = u.partition(":") if u.startswith("/dev/") else (u, "", "")
        return dev, _baud(b, baud, url)
    raise ConfigError(
        f"connection URL {url!r} not understood (udpin:H:P, udpout:H:P, tcp:H:P, /dev/ttyX, udp://:P)"
    )


#: bind addresses that listen on every network interface
ALL_INTERFACES = ("0.0.0.0", "::", "", "*")


def warn_if_all_interfaces(what: str, host: str) -> bool:
    """Log (and return True) when ``host`` binds all interfaces: anyone on any network the
    machine is on can then send commands, parameters and setpoints to the port."""
    if host.strip("[]") not in ALL_INTERFACES:
        return False
    log.warning(
        "%s listens on ALL network interfaces (%s): any host that can reach this port can "
        "send it commands, PARAM_SETs and setpoints. Bind to 127.0.0.1 or one interface "
        "address (e.g. udpin:127.0.0.1:14540) and use MAVLink signing on shared networks",
        what,
        host or "no host given",
    )
    return True


def _port(p: str, url: str) -> int:
    try:
        v = int(p)
    except ValueError:
        raise ConfigError(f"connection URL {url!r}: port {p!r} is not an integer") from None
    if not 0 < v < 65536:
        raise ConfigError(f"connection URL {url!r}: port {v} out of range")
    return v


def _baud(b: str, default: int, url: str) -> int:
    if not b:
        return default
    try:
        v = int(b)
    except ValueError:
        raise ConfigError(f"connection URL {url!r}: baud {b!r} is not an integer") from None
    if v <= 0:
        raise ConfigError(f"connection URL {url!r}: baud must be positive")
    return v


def load_signing_key(path: str) -> bytes:
    """Read a MAVLink 2 signing secret: 32 raw bytes, or 64 hexadecimal characters."""
    from lpv_sysid.errors import FileReadError
    from lpv_sysid.io.safe_open import read_bytes

    try:  # regular files only (a FIFO would block the reader), at most 4 KiB
        raw = read_bytes(path, f"signing key file {path!r}", max_bytes=4096)
    except FileReadError as exc:
        raise ConfigError(f"signing key file {path!r} cannot be read: {exc.reason}") from None
    if len(raw) == 32:
        return raw
    text = raw.strip()
    if len(text) == 64:
        try:
            return binascii.unhexlify(text)
        except (binascii.Error, ValueError):
            raise ConfigError(
                f"signing key file {path!r}: 64 characters but not hexadecimal"
            ) from None
    raise ConfigError(
        f"signing key file {path!r}: expected 32 raw bytes or 64 hex characters, "
        f"got {len(raw)} bytes"
    )


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
    kind: str  # "link_up" | "link_lost" | "reconnect" | "io_error"
    detail: str = ""


# ------------------------------------------------------------------ fast decode
#: telemetry the bridge receives at high rate: decoded by :class:`FastDecoder` (the rest, and
#: anything unusual, by pymavlink)
FAST_MESSAGES = (
    "HEARTBEAT",
    "ATTITUDE",
    "ATTITUDE_QUATERNION",
    "LOCAL_POSITION_NED",
    "HIGHRES_IMU",
    "ODOMETRY",
    "SERVO_OUTPUT_RAW",
    "ACTUATOR_OUTPUT_STATUS",
    "ESC_STATUS",
)
_REV8 = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))
_V2_HEADER = struct.Struct("<BBBBBBBHB")  # magic, len, incompat, compat, seq, sys, comp, id


def x25_crc(data: bytes, extra: int | None = None) -> int:
    """MAVLink's X.25 (CRC-16/MCRF4XX) of ``data`` (+ the CRC_EXTRA byte), computed with the
    C ``binascii.crc_hqx`` (CRC-16/CCITT-FALSE) on bit-reversed bytes: MCRF4XX is its
    reflected form with the same polynomial and initial value."""
    c = binascii.crc_hqx(data.translate(_REV8), 0xFFFF)
    if extra is not None:
        c = binascii.crc_hqx(_REV8[extra : extra + 1], c)
    return (_REV8[c & 0xFF] << 8) | _REV8[c >> 8]


class FastDecoder:
    """Struct-based decode of whole MAVLink 2 datagrams of the :data:`FAST_MESSAGES`, giving
    the objects pymavlink's ``parse_buffer`` gives: the dialect classes with the same
    attributes (fields, ``_header``, ``_msgbuf``, ``_payload``, ``_crc``, ...) in the same
    order, learned from a template packet the codec itself decoded. Each packet's X.25 CRC
    (with CRC_EXTRA) is checked over the packet bytes. :meth:`decode` stops at the first
    byte it does not handle -- a bad prefix or CRC, a MAVLink 1 or signed packet, another
    message id, a cut packet -- and returns the offset, from where pymavlink parses the rest
    (so bad data is counted and resynchronised exactly as before). Not used while signing
    is configured (:meth:`MavlinkLink._fast_decoder`)."""

    def __init__(self, codec: Any, mod: Any) -> None:
        self.codec = codec
        #: msg id -> (crc_extra byte, payload size, unpack_from, unpack, make(t, mlen, seq,
        #: sys, comp, compat, msgbuf, crc))
        self.specs: dict[int, tuple] = {}
        for name in FAST_MESSAGES:
            mid = (
                px4.MAVLINK_MSG_ID_ESC_STATUS
                if name == "ESC_STATUS"
                else getattr(mod, f"MAVLINK_MSG_ID_{name}", None)
            )
            if mid is not None:
                spec = self._spec(codec, mod, int(mid))
                if spec is not None:
                    self.specs[int(mid)] = spec

    @staticmethod
    def _spec(codec: Any, mod: Any, mid: int):
        cls = mod.mavlink_map.get(mid)
        esc = cls is None and mid == px4.MAVLINK_MSG_ID_ESC_STATUS
        if esc:
            crc_extra, unpacker = px4.ESC_STATUS_CRC_EXTRA, px4._ESC_STATUS_STRUCT
        elif cls is None:
            return None
        else:
            crc_extra, unpacker = cls.crc_extra, cls.unpacker
        # the codec decodes a packet of this id (1-byte payload: MAVLink 2 zero truncation)
        body = _V2_HEADER.pack(0xFD, 1, 0, 0, 0, 1, 1, mid & 0xFFFF, mid >> 16)[1:] + b"\x00"
        probe = codec.decode(
            bytearray(b"\xfd" + body + struct.pack("<H", x25_crc(body, crc_extra)))
        )
        if probe is None or probe.get_msgId() != mid:
            return None
        cls = type(probe)
        if esc:  # px4._decode_esc_status: cls(index, time_usec, rpm, voltage, current)
            fields = {
                "index": "int(t[13])",
                "time_usec": "int(t[0])",
                "rpm": "[int(t[1]), int(t[2]), int(t[3]), int(t[4])]",
                "voltage": "[float(t[5]), float(t[6]), float(t[7]), float(t[8])]",
                "current": "[float(t[9]), float(t[10]), float(t[11]), float(t[12])]",
            }
            payload = "msgbuf[10:10 + mlen]"
        else:  # pymavlink's decode: wire order -> field order, arrays as lists
            lengths, orders = list(cls.lengths), list(cls.orders)
            fmt = unpacker.format
            fields = {}
            for name, o in zip(cls.fieldnames, orders):
                tip, n = (sum(lengths[:o]), lengths[o]) if sum(lengths) != len(lengths) else (o, 1)
                fields[name] = (
                    f"t[{tip}]"
                    if n == 1
                    else "[" + ", ".join(f"t[{tip + k}]" for k in range(n)) + "]"
                )
            if "s" in fmt:  # char[] fields (bytes values): left to pymavlink
                return None
            payload = "msgbuf[6:-2]"
        variable = {
            "_header": "h",
            "_msgbuf": "msgbuf",
            "_payload": payload,
            "_crc": "crc",
            "_signed": "False",
            **fields,
        }
        consts: dict[str, Any] = {}
        items = []
        for key, val in probe.__dict__.items():
            if key in variable:
                items.append(f"{key!r}: {variable[key]}")
            else:
                consts[f"c{len(consts)}"] = val
                items.append(f"{key!r}: c{len(consts) - 1}")
        missing = set(variable) - set(probe.__dict__)
        if missing:
            return None
        hkeys = list(probe._header.__dict__)
        hexpr = {
            "mlen": "mlen",
            "seq": "seq",
            "srcSystem": "sysid",
            "srcComponent": "compid",
            "msgId": str(mid),
            "incompat_flags": "0",
            "compat_flags": "compat",
        }
        if set(hkeys) != set(hexpr):
            return None
        src = (
            "def make(t, mlen, seq, sysid, compid, compat, msgbuf, crc):\n"
            "    h = _new(_H)\n"
            "    h.__dict__ = {" + ", ".join(f"{k!r}: {hexpr[k]}" for k in hkeys) + "}\n"
            "    m = _new(_C)\n"
            "    m.__dict__ = {" + ", ".join(items) + "}\n"
            "    return m\n"
        )
        ns = {
            "_new": object.__new__,
            "_H": type(probe._header),
            "_C": cls,
            "_strip": lambda b: b.rstrip(b"\x00"),
            **consts,
        }
        exec(compile(src, f"<lpv_sysid.mavlink fast decode {cls.__name__}>", "exec"), ns)  # noqa: S102
        return (
            _REV8[crc_extra : crc_extra + 1],
            unpacker.size,
            unpacker.unpack_from,
            unpacker.unpack,
            ns["make"],
        )

    def decode(
        self, data: bytes, out: list, counts: dict, last_seq: dict
    ) -> tuple[int, int, int, list]:
        """Decode packets of ``data`` from offset 0, appending the messages to ``out`` and
        counting them per id (``counts``) and source (``last_seq``: last sequence number).
        Returns (offset of the first byte not handled, messages, sequence numbers lost,
        the HEARTBEAT messages)."""
        specs = self.specs
        crc_hqx = binascii.crc_hqx
        rev = None
        pos, n, got, lost = 0, len(data), 0, 0
        beats = []
        while pos + 12 <= n:
            if data[pos] != 0xFD or data[pos + 2]:  # MAVLink 1, bad prefix, incompat flags
                break
            mlen = data[pos + 1]
            end = pos + 12 + mlen
            mid = data[pos + 7] | data[pos + 8] << 8 | data[pos + 9] << 16
            spec = specs.get(mid)
            if spec is None or end > n:
                break
            extra, csize, unpack_from, unpack, make = spec
            if rev is None:
                rev = data.translate(_REV8)
            c = crc_hqx(extra, crc_hqx(rev[pos + 1 : pos + 10 + mlen], 0xFFFF))
            crc = data[end - 2] | data[end - 1] << 8
            if crc != (_REV8[c & 0xFF] << 8) | _REV8[c >> 8]:
                break  # pymavlink reports the bad CRC
            try:
                if mlen >= csize:
                    t = unpack_from(data, pos + 10)
                else:
                    t = unpack(data[pos + 10 : pos + 10 + mlen] + bytes(csize - mlen))
            except struct.error:
                break
            seq, sysid, compid = data[pos + 4], data[pos + 5], data[pos + 6]
            m = make(
                t,
                mlen,
                seq,
                sysid,
                compid,
                data[pos + 3],
                bytearray(data) if pos == 0 and end == n else bytearray(data[pos:end]),
                crc,
            )
            out.append(m)
            counts[mid] = counts.get(mid, 0) + 1
            key = (sysid, compid)
            last = last_seq.get(key)
            if last is not None:
                gap = (seq - last - 1) % 256
                if gap < 128:  # larger jumps are restarts, not losses
                    lost += gap
            last_seq[key] = seq
            if mid == MSG_HEARTBEAT:
                beats.append(m)
            got += 1
            pos = end
        return pos, got, lost, beats


class MavlinkLink:
    """A polled MAVLink 2 connection (see module docstring).

    ``connection_factory(device, baud, source_system, source_component)`` may be injected
    (tests); by default ``mavutil.mavlink_connection`` is used.
    """

    def __init__(
        self, config: LinkConfig, connection_factory: Callable[..., Any] | None = None
    ) -> None:
        config.validate()
        self.config = config
        self.stats = LinkStats()
        self._factory = connection_factory or _mavutil_connection
        self._device, self._baud = parse_url(config.url, config.baud)
        self._key = load_signing_key(config.signing_key_file) if config.signing_key_file else None
        self._mod = px4.dialect_module(config.dialect)
        self.conn: Any = None
        self.codec: Any = None
        self.target_system = config.target_system
        self.target_component = config.target_component
        self.last_heartbeat: Any = None  # last HEARTBEAT message of the target
        self.last_heartbeat_t: float | None = None
        self._up = False
        self._next_hb = 0.0
        self._next_stream_req = 0.0
        self._last_reopen = 0.0
        self._counts: dict[int, int] = {}
        self._last_rx = -float("inf")
        self._requested_once = False
        self._last_seq: dict[tuple[int, int], int] = {}
        self._stream_ids = [(self._msg_id(n), r) for n, r in config.streams]
        self._events: list[LinkEvent] = []
        self._fast: FastDecoder | None = None
        self._no_fast: Any = None  # a codec FastDecoder could not be built for

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
        self.codec = px4.make_codec(
            self.conn, self.config.source_system, self.config.source_component, self.config.dialect
        )
        if self._key is not None:
            px4.setup_signing(
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
            self.last_heartbeat_t is not None
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
            return px4.MAVLINK_MSG_ID_ESC_STATUS
        return int(getattr(self._mod, f"MAVLINK_MSG_ID_{name}"))

    def _on_heartbeat(self, m: Any, now: float) -> None:
        if m.autopilot == MAV_AUTOPILOT_INVALID or m.type in (
            MAV_TYPE_GCS,
            MAV_TYPE_ONBOARD_CONTROLLER,
        ):
            return
        src = m.get_srcSystem()
        if self.target_system == 0:
            self.target_system = src
            self.target_component = m.get_srcComponent()
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

    def _device_reopens(self) -> bool:
        # UDP sockets stay valid when the peer goes away; serial/TCP are reopened.
        return not self._is_datagram()

    def _reset_parser(self) -> None:
        c = self.codec
        c.buf = bytearray()
        c.buf_index = 0
        c.expected_length = self._mod.HEADER_LEN_V1 + 2

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


__all__ = [
    "LinkConfig",
    "LinkStats",
    "LinkEvent",
    "MavlinkLink",
    "parse_url",
    "load_signing_key",
    "free_udp_port",
    "warn_if_all_interfaces",
    "DEFAULT_STREAMS",
]
