"""A minimal PX4 ULog writer for tests, written from PX4's file format specification
(docs "ULog File Format", version 1): a 16-byte header (magic ``ULog`` 0x01 0x12 0x35,
version, uint64 start timestamp), the flag-bits message ``B`` right after it, the definitions
section (``F`` formats, ``I`` info, ``P`` parameters) and the data section (``A`` add logged
message, ``D`` data, ``L`` logged string). Every message: uint16 size (of the payload),
uint8 type, payload; little endian, fields packed without padding. Independent of pyulog
(the reader under test)."""

from __future__ import annotations

import struct
from typing import Any, Mapping, Sequence

MAGIC = b"ULog\x01\x12\x35"
_TYPES = {
    "int8_t": "b",
    "uint8_t": "B",
    "int16_t": "h",
    "uint16_t": "H",
    "int32_t": "i",
    "uint32_t": "I",
    "int64_t": "q",
    "uint64_t": "Q",
    "float": "f",
    "double": "d",
    "bool": "?",
    "char": "c",
}


def _msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


class ULogWriter:
    """Build a ULog in memory: formats, info, parameters, then subscriptions and data."""

    def __init__(self, start_us: int) -> None:
        self.start_us = int(start_us)
        self.formats: dict[str, list[tuple[str, int, str]]] = {}  # name -> (type, n, field)
        self._defs: list[bytes] = []
        self._data: list[bytes] = []
        self._ids: dict[tuple[str, int], int] = {}

    # -- definitions
    def format(self, name: str, fields: Sequence[str]) -> None:
        """``fields``: ``"uint64_t timestamp"``, ``"float[4] q"``, ``"esc_report[8] esc"``."""
        parsed = []
        for f in fields:
            typ, fname = f.split()
            n = 1
            if "[" in typ:
                typ, rest = typ.split("[")
                n = int(rest.rstrip("]"))
            parsed.append((typ, n, fname))
        self.formats[name] = parsed
        self._defs.append(_msg(b"F", f"{name}:{';'.join(fields)};".encode()))

    def info(self, ctype: str, key: str, value: Any) -> None:
        """``I``: e.g. ``info("char[11]", "ver_hw", "PX4_SITL")`` or ``("uint32_t", ...)``."""
        if ctype.startswith("char"):
            val = str(value).encode()
            ctype = f"char[{len(val)}]"
        else:
            val = struct.pack("<" + _TYPES[ctype], value)
        k = f"{ctype} {key}".encode()
        self._defs.append(_msg(b"I", bytes([len(k)]) + k + val))

    def param(self, key: str, value: int | float) -> None:
        ctype = "int32_t" if isinstance(value, int) else "float"
        k = f"{ctype} {key}".encode()
        val = struct.pack("<" + _TYPES[ctype], value)
        self._defs.append(_msg(b"P", bytes([len(k)]) + k + val))

    # -- data
    def add(self, name: str, multi_id: int = 0) -> int:
        msg_id = len(self._ids)
        self._ids[(name, multi_id)] = msg_id
        self._data.append(_msg(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode()))
        return msg_id

    def _pack(self, fmt: str, values: Mapping[str, Any], prefix: str = "") -> bytes:
        out = b""
        for typ, n, fname in self.formats[fmt]:
            for i in range(n):
                key = f"{prefix}{fname}" if n == 1 else f"{prefix}{fname}[{i}]"
                if typ in _TYPES:
                    v = values.get(key, 0)
                    if typ == "char":
                        v = bytes([v]) if isinstance(v, int) else (v or b"\0")[:1]
                    out += struct.pack("<" + _TYPES[typ], v)
                else:  # nested message
                    out += self._pack(typ, values, key + ".")
        return out

    def data(self, name: str, values: Mapping[str, Any], multi_id: int = 0) -> None:
        """``D``: one sample of ``name`` (flattened keys: ``q[0]``, ``esc[1].esc_rpm``)."""
        msg_id = self._ids[(name, multi_id)]
        self._data.append(_msg(b"D", struct.pack("<H", msg_id) + self._pack(name, values)))

    def log(self, level: int, timestamp_us: int, text: str) -> None:
        self._data.append(_msg(b"L", struct.pack("<BQ", level, timestamp_us) + text.encode()))

    def bytes(self) -> bytes:
        header = MAGIC + bytes([1]) + struct.pack("<Q", self.start_us)
        flags = _msg(b"B", bytes(16) + struct.pack("<QQQ", 0, 0, 0))
        return header + flags + b"".join(self._defs) + b"".join(self._data)
