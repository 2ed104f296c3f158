"""The MAVLink 2 codec every link uses: the pymavlink dialect plus PX4's ESC_STATUS,
robust parsing, and MAVLink 2 signing.

ESC_STATUS (id 291) is sent by PX4 but is not part of the dialects bundled with
pymavlink 2.4.50, so it is defined here with the field layout and CRC_EXTRA of
mavlink/message_definitions common.xml (CRC_EXTRA 10, verified against
``pymavlink.generator.mavparse`` in the tests).
"""

from __future__ import annotations

import importlib
import struct
import time
from types import ModuleType
from typing import Any

from lpv_sysid.errors import ConfigError

MAVLINK_MSG_ID_ESC_STATUS = 291
ESC_STATUS_CRC_EXTRA = 10
_ESC_STATUS_STRUCT = struct.Struct(
    "<Q4i4f4fB"
)  # wire order: time_usec, rpm, voltage, current, index

DEFAULT_DIALECT = "development"  # PX4 builds its MAVLink with development.xml (includes common)
_DIALECTS = ("development", "common", "ardupilotmega", "all")


def dialect_module(name: str = DEFAULT_DIALECT) -> ModuleType:
    """The pymavlink MAVLink-2 dialect module (``pymavlink.dialects.v20.<name>``)."""
    if name not in _DIALECTS:
        raise ConfigError(f"mavlink dialect {name!r} not supported; use one of {_DIALECTS}")
    return importlib.import_module(f"pymavlink.dialects.v20.{name}")


_CODEC_CLASSES: dict[str, type] = {}


def esc_status_class(name: str = DEFAULT_DIALECT) -> type:
    """MAVLink_esc_status_message class built on the dialect's MAVLink_message base."""
    return _codec_classes(name)[1]


def _codec_classes(name: str) -> tuple[type, type]:
    if name in _CODEC_CLASSES:
        return _CODEC_CLASSES[name], _CODEC_CLASSES[name + ":esc"]
    mod = dialect_module(name)

    # the dialect's classes are attributes of a module loaded at run time (name-defined)
    class EscStatusMessage(mod.MAVLink_message):  # type: ignore[name-defined]
        """ESC_STATUS (291): index, time_usec [us], rpm[4], voltage[4] [V], current[4] [A]."""

        id = MAVLINK_MSG_ID_ESC_STATUS
        msgname = "ESC_STATUS"
        fieldnames = ["index", "time_usec", "rpm", "voltage", "current"]
        ordered_fieldnames = ["time_usec", "rpm", "voltage", "current", "index"]
        crc_extra = ESC_STATUS_CRC_EXTRA
        unpacker = _ESC_STATUS_STRUCT
        instance_field = None
        instance_offset = -1

        def __init__(self, index: int, time_usec: int, rpm, voltage, current) -> None:
            mod.MAVLink_message.__init__(self, MAVLINK_MSG_ID_ESC_STATUS, "ESC_STATUS")
            self._fieldnames = self.fieldnames
            self._instance_field = None
            self._instance_offset = -1
            self.index = int(index)
            self.time_usec = int(time_usec)
            self.rpm = [int(x) for x in rpm]
            self.voltage = [float(x) for x in voltage]
            self.current = [float(x) for x in current]

        def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes:
            payload = _ESC_STATUS_STRUCT.pack(
                self.time_usec, *self.rpm, *self.voltage, *self.current, self.index
            )
            return self._pack(mav, self.crc_extra, payload, force_mavlink1=force_mavlink1)

    class Px4Codec(mod.MAVLink):  # type: ignore[name-defined]  # see EscStatusMessage
        """The dialect's MAVLink parser plus ESC_STATUS; robust parsing always on."""

        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.robust_parsing = True

        def decode(self, msgbuf: bytearray):  # noqa: D102 - pymavlink API
            m = super().decode(msgbuf)
            if (
                isinstance(m, mod.MAVLink_unknown)
                and msgbuf[0] == mod.PROTOCOL_MARKER_V2
                and (msgbuf[7] | msgbuf[8] << 8 | msgbuf[9] << 16) == MAVLINK_MSG_ID_ESC_STATUS
            ):
                return _decode_esc_status(self, mod, EscStatusMessage, msgbuf)
            return m

    _CODEC_CLASSES[name] = Px4Codec
    _CODEC_CLASSES[name + ":esc"] = EscStatusMessage
    return Px4Codec, EscStatusMessage


def _decode_esc_status(codec: Any, mod: ModuleType, cls: type, msgbuf: bytearray):
    """Decode ESC_STATUS with CRC and signature checks, mirroring pymavlink's decode()."""
    signed = bool(msgbuf[2] & mod.MAVLINK_IFLAG_SIGNED)
    mlen = msgbuf[1]
    crc = struct.unpack("<H", bytes(msgbuf[10 + mlen : 12 + mlen]))[0]
    crcbuf = bytearray(msgbuf[1 : 10 + mlen])
    crcbuf.append(ESC_STATUS_CRC_EXTRA)
    if crc != mod.x25crc(crcbuf).crc:
        raise mod.MAVError("invalid MAVLink CRC in msgID 291")
    src_sys, src_comp = msgbuf[5], msgbuf[6]
    if codec.signing.secret_key is not None:
        ok = signed and codec.check_signature(msgbuf, src_sys, src_comp)
        if not ok and not (
            codec.signing.allow_unsigned_callback is not None
            and codec.signing.allow_unsigned_callback(codec, 291)
        ):
            codec.signing.badsig_count += 1
            raise mod.MAVError("Invalid signature")
    payload = bytes(msgbuf[10 : 10 + mlen]).ljust(_ESC_STATUS_STRUCT.size, b"\0")
    t = _ESC_STATUS_STRUCT.unpack(payload[: _ESC_STATUS_STRUCT.size])
    m = cls(t[13], t[0], t[1:5], t[5:9], t[9:13])
    m._msgbuf = msgbuf
    m._payload = msgbuf[10 : 10 + mlen]
    m._crc = crc
    m._signed = signed
    m._header = mod.MAVLink_header(291, msgbuf[2], msgbuf[3], mlen, msgbuf[4], src_sys, src_comp)
    return m


def make_codec(
    file: Any, source_system: int, source_component: int, dialect: str = DEFAULT_DIALECT
) -> Any:
    """A MAVLink 2 parser/packer for ``file`` (anything with ``write(bytes)``)."""
    cls, _ = _codec_classes(dialect)
    return cls(file, srcSystem=source_system, srcComponent=source_component)


SIGNING_EPOCH = 1420070400  # 2015-01-01T00:00:00Z, MAVLink signing timestamp origin


def setup_signing(
    codec: Any,
    key: bytes,
    link_id: int = 0,
    allow_unsigned: bool = False,
    wall_time: float | None = None,
) -> None:
    """Enable MAVLink 2 signing on ``codec`` (timestamp in 10 us since 2015-01-01)."""
    if len(key) != 32:
        raise ConfigError(f"MAVLink signing key must be 32 bytes, got {len(key)}")
    codec.signing.secret_key = bytes(key)
    codec.signing.sign_outgoing = True
    codec.signing.link_id = int(link_id) & 0xFF
    codec.signing.allow_unsigned_callback = (lambda _mav, _msgid: True) if allow_unsigned else None
    now = time.time() if wall_time is None else wall_time
    codec.signing.timestamp = int(max(now - SIGNING_EPOCH, 0.0) * 100_000)
