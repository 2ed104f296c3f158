"""Struct-based decode of the high-rate MAVLink 2 telemetry (:class:`FastDecoder`): the same
message objects pymavlink gives, X.25 CRC with CRC_EXTRA checked; anything unusual is left to
pymavlink."""

from __future__ import annotations

import binascii
import struct
from typing import Any

from lpv_sysid.mavlink.codec import (
    _ESC_STATUS_STRUCT,
    ESC_STATUS_CRC_EXTRA,
    MAVLINK_MSG_ID_ESC_STATUS,
)
from lpv_sysid.mavlink.link.config import MSG_HEARTBEAT

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
    is configured (:meth:`lpv_sysid.mavlink.link.receive.LinkReceiver._fast_decoder`)."""

    def __init__(self, codec: Any, mod: Any) -> None:
        self.codec = codec
        #: msg id -> (crc_extra byte, payload size, unpack_from, unpack, make(t, mlen, seq,
        #: sys, comp, compat, msgbuf, crc))
        self.specs: dict[int, tuple] = {}
        for name in FAST_MESSAGES:
            mid = (
                MAVLINK_MSG_ID_ESC_STATUS
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
        esc = cls is None and mid == MAVLINK_MSG_ID_ESC_STATUS
        if esc:
            crc_extra, unpacker = ESC_STATUS_CRC_EXTRA, _ESC_STATUS_STRUCT
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
