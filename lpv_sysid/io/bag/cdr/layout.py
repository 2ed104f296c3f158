"""The CDR block codec: fixed-layout records decoded and encoded a topic at a time.

The messages this package writes have a fixed layout per topic: their strings (frame ids,
joint names) and sequence lengths do not change from one message to the next, so every
numeric field sits at the same byte offset of every record. Such records are decoded (and
encoded) for a whole topic at once as rows of a numpy structured array. The layout of a
group of records is derived from one of them deserialised by rosbags (the "template") and
is used only after a probe check: a copy of the template with a distinct value in every
numeric field is serialised by rosbags and must decode to exactly those values through
the layout (and encode back to the same bytes). Records whose structural bytes (the CDR
encapsulation header, string lengths and contents, sequence counts) differ from the
template's form another group; anything the layout cannot describe goes through
rosbags' own ``deserialize_cdr``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from lpv_sysid.errors import BagError
from lpv_sysid.io.bag.typestore import jazzy_typestore

LOG = logging.getLogger(__name__)

_CDR_PRIMITIVES = {  # ROS 2 base type -> little-endian numpy dtype (size = alignment)
    "bool": "?",
    "byte": "i1",
    "char": "u1",
    "int8": "i1",
    "uint8": "u1",  # as rosbags
    "int16": "<i2",
    "uint16": "<u2",
    "int32": "<i4",
    "uint32": "<u4",
    "int64": "<i8",
    "uint64": "<u8",
    "float32": "<f4",
    "float64": "<f8",
}
_MAX_LAYOUT_GROUPS = 8  # distinct layouts per topic before the rest goes through rosbags


class LayoutError(BagError):
    """A message type or record that the fixed-layout codec cannot describe."""


@dataclass(frozen=True)
class _Leaf:
    path: str  # "pose.pose.position.x", "velocity", "status[0].level"
    offset: int  # byte offset in the record (the 4 header bytes included)
    rostype: str
    count: int | None  # None: scalar; n: fixed array or sequence of n elements

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(_CDR_PRIMITIVES[self.rostype])

    @property
    def nbytes(self) -> int:
        return self.dtype.itemsize * (1 if self.count is None else self.count)


@dataclass
class _LayoutWalk:
    leaves: list = field(default_factory=list)
    strings: dict = field(default_factory=dict)
    struct: list = field(default_factory=lambda: [np.arange(4)])  # the encapsulation header
    counts: dict = field(default_factory=dict)


class CdrLayout:
    """Byte layout of one CDR record shape: numeric leaves, strings, structural bytes.

    Built by :meth:`from_message` from a rosbags message; :meth:`decode` turns an (N, size)
    uint8 block of records with this shape into arrays per leaf, :meth:`encode` writes arrays
    into copies of the template record.
    """

    def __init__(
        self,
        msgtype: str,
        template: bytes,
        leaves: list,
        strings: dict,
        struct_index: np.ndarray,
        counts: dict | None = None,
    ):
        self.msgtype = msgtype
        self.counts = dict(counts or {})  # path -> length of every array / sequence
        self.template = bytes(template)
        self.size = len(self.template)
        self.leaves = {lf.path: lf for lf in leaves}
        self.strings = strings  # path -> str, or tuple of str for string arrays
        self.struct_index = struct_index  # byte positions that must equal the template's
        self.struct_bytes = np.frombuffer(self.template, np.uint8)[struct_index]
        self.dtype = np.dtype(
            {
                "names": [lf.path for lf in leaves],
                "formats": [
                    lf.dtype if lf.count is None else (lf.dtype, (lf.count,)) for lf in leaves
                ],
                "offsets": [lf.offset for lf in leaves],
                "itemsize": self.size,
            }
        )

    # -- construction ---------------------------------------------------------
    @classmethod
    def from_message(cls, typestore, msgtype: str, msg, data: bytes | None = None) -> "CdrLayout":
        """Layout of ``msg`` (a rosbags message of ``msgtype``); ``data`` is its CDR record
        (serialised here when None). Raises :class:`LayoutError` for a type it cannot
        describe (float128, wstring) or a record rosbags did not write little-endian."""
        if data is None:
            data = bytes(typestore.serialize_cdr(msg, msgtype))
        data = bytes(data)
        if data[:2] != b"\x00\x01":
            raise LayoutError(
                f"{msgtype}: CDR encapsulation {data[:2].hex()} is not little-endian"
            )
        acc = _LayoutWalk()
        end = cls._walk(typestore, msgtype, msg, 0, "", acc)
        if not 4 + end <= len(data) <= 4 + end + 3:
            raise LayoutError(
                f"{msgtype}: layout covers {4 + end} bytes, the record has {len(data)}"
            )
        return cls(
            msgtype,
            data,
            acc.leaves,
            acc.strings,
            np.concatenate(acc.struct).astype(np.intp),
            acc.counts,
        )

    @classmethod
    def _walk(cls, ts, msgtype, msg, pos, prefix, acc) -> int:
        try:
            fields_ = ts.fielddefs[msgtype][1]
        except KeyError:
            raise LayoutError(f"unknown message type {msgtype!r}") from None
        for name, desc in fields_:
            pos = cls._field(ts, desc, getattr(msg, name), pos, prefix + name, acc)
        return pos

    @classmethod
    def _field(cls, ts, desc, val, pos, path, acc) -> int:
        from rosbags.interfaces import Nodetype

        kind, arg = desc
        if kind == Nodetype.NAME:
            return cls._walk(ts, arg, val, pos, path + ".", acc)
        if kind == Nodetype.BASE:
            t = arg[0]
            if t == "string":
                acc.strings[path] = val
                return cls._string(val, pos, acc)
            size = cls._size(t)
            pos = -(-pos // size) * size
            acc.leaves.append(_Leaf(path, 4 + pos, t, None))
            return pos + size
        if kind == Nodetype.ARRAY:
            sub, n = arg
        elif kind == Nodetype.SEQUENCE:
            sub, n = arg[0], len(val)
            pos = -(-pos // 4) * 4
            acc.struct.append(np.arange(4 + pos, 8 + pos))
            pos += 4
        else:
            raise LayoutError(f"{path}: unsupported field kind {kind}")
        acc.counts[path] = n
        if sub[0] == Nodetype.BASE and sub[1][0] != "string":
            size = cls._size(sub[1][0])
            if n:
                pos = -(-pos // size) * size
            acc.leaves.append(_Leaf(path, 4 + pos, sub[1][0], n))
            return pos + n * size
        if sub[0] == Nodetype.BASE:  # strings
            acc.strings[path] = tuple(val)
            for item in val:
                pos = cls._string(item, pos, acc)
            return pos
        for i in range(n):
            pos = cls._walk(ts, sub[1], val[i], pos, f"{path}[{i}].", acc)
        return pos

    @staticmethod
    def _size(rostype: str) -> int:
        try:
            return np.dtype(_CDR_PRIMITIVES[rostype]).itemsize
        except KeyError:
            raise LayoutError(f"base type {rostype!r} has no fixed-layout codec") from None

    @staticmethod
    def _string(text, pos, acc) -> int:
        pos = -(-pos // 4) * 4
        n = len(text.encode()) + 1
        acc.struct.append(np.arange(4 + pos, 8 + pos + n))
        return pos + 4 + n

    # -- use ---------------------------------------------------------------------
    def matches(self, block: np.ndarray) -> np.ndarray:
        """Rows of the (N, size) uint8 ``block`` whose structural bytes equal the template's."""
        return (block[:, self.struct_index] == self.struct_bytes).all(axis=1)

    def decode(self, block: np.ndarray) -> dict:
        """``{path: array}`` (N,) or (N, count) of every numeric leaf of the rows of ``block``."""
        rec = np.ascontiguousarray(block).reshape(-1).view(self.dtype)
        out = {}
        for name in self.dtype.names or ():
            a = np.array(rec[name])
            if a.dtype.kind == "b":  # any non-zero byte is True, as for rosbags
                a = a.view(np.uint8) != 0
            out[name] = a
        return out

    def encode(self, n: int, values: Mapping) -> np.ndarray:
        """(n, size) uint8 block: ``n`` copies of the template with the leaves in ``values``
        (path -> array of n rows) replaced; integers must fit their field."""
        unknown = sorted(set(values) - set(self.leaves))
        if unknown:
            raise LayoutError(
                f"{self.msgtype}: no numeric field(s) {unknown}; fields: {list(self.leaves)}"
            )
        block = np.empty((n, self.size), np.uint8)
        block[:] = np.frombuffer(self.template, np.uint8)
        rec = block.reshape(-1).view(self.dtype)
        for path, v in values.items():
            lf = self.leaves[path]
            a = np.asarray(v)
            shape = (n,) if lf.count is None else (n, lf.count)
            if a.shape != shape:
                raise LayoutError(f"{self.msgtype}.{path}: expected shape {shape}, got {a.shape}")
            if lf.dtype.kind in "iu" and a.size:
                info = np.iinfo(lf.dtype)
                if a.dtype.kind not in "iub" or a.min() < info.min or a.max() > info.max:
                    raise LayoutError(f"{self.msgtype}.{path}: values outside {lf.rostype}")
            rec[path] = a
        return block

    def probe(self, typestore) -> None:
        """Check the layout against rosbags on a copy of the template that carries a distinct
        value in every numeric field; raises :class:`LayoutError` on any difference."""
        rng = np.random.default_rng(len(self.leaves) * 7919 + self.size)
        msg = typestore.deserialize_cdr(self.template, self.msgtype)
        values = {}
        for path, lf in self.leaves.items():
            shape = () if lf.count is None else (lf.count,)
            if lf.dtype.kind == "b":
                v = rng.integers(0, 2, shape).astype(bool)
            elif lf.dtype.kind in "iu":
                info = np.iinfo(lf.dtype)
                v = rng.integers(
                    max(info.min, -(2**40)), min(info.max, 2**40), shape, endpoint=True
                ).astype(lf.dtype)
            else:
                v = rng.normal(size=shape).astype(lf.dtype) * 1e3
            values[path] = v
            _set_path(msg, path, v if lf.count is not None else v.item())
        data = np.frombuffer(bytes(typestore.serialize_cdr(msg, self.msgtype)), np.uint8)
        if data.size != self.size or not np.array_equal(
            data[self.struct_index], self.struct_bytes
        ):
            raise LayoutError(f"{self.msgtype}: probe record does not have the template's shape")
        got = self.decode(data.reshape(1, -1))
        for path, v in values.items():
            if not np.array_equal(got[path][0], v):
                raise LayoutError(f"{self.msgtype}.{path}: layout offset disagrees with rosbags")
        back = self.encode(1, {p: np.asarray(v)[None] for p, v in values.items()})[0]
        keep = np.zeros(self.size, bool)
        keep[self.struct_index] = True
        for lf in self.leaves.values():
            keep[lf.offset : lf.offset + lf.nbytes] = True
        if not np.array_equal(back[keep], data[keep]):
            raise LayoutError(f"{self.msgtype}: layout encoding disagrees with rosbags")


def _set_path(msg, path: str, value) -> None:
    obj = msg
    parts = path.replace("]", "").replace("[", ".").split(".")
    for p in parts[:-1]:
        obj = obj[int(p)] if p.isdigit() else getattr(obj, p)
    setattr(obj, parts[-1], value)


def _get_path(msg, path: str):
    obj = msg
    for p in path.replace("]", "").replace("[", ".").split("."):
        obj = obj[int(p)] if p.isdigit() else getattr(obj, p)
    return obj


class _LayoutCache:
    """Probed layouts per (msgtype, record length, structural bytes), shared by all reads."""

    def __init__(self) -> None:
        self._by_key: dict[tuple, CdrLayout] = {}
        self._bad: set[tuple] = set()

    def for_record(self, typestore, msgtype: str, data: bytes) -> CdrLayout | None:
        """The probed layout of the record ``data`` (None when it has none)."""
        msg = typestore.deserialize_cdr(data, msgtype)
        key = None
        try:
            lay = CdrLayout.from_message(typestore, msgtype, msg, data)
            key = (
                id(typestore),
                msgtype,
                lay.size,
                lay.struct_bytes.tobytes(),
                lay.struct_index.tobytes(),
            )
            hit = self._by_key.get(key)
            if hit is not None:
                return hit
            if key in self._bad:
                return None
            lay.probe(typestore)
        except LayoutError as exc:
            LOG.debug("no block codec for %s: %s", msgtype, exc)
            if key is not None:
                self._bad.add(key)
            return None
        self._by_key[key] = lay
        return lay

    def for_message(self, typestore, msgtype: str, msg) -> CdrLayout:
        """The probed layout of the message ``msg`` (raises :class:`LayoutError`)."""
        lay = CdrLayout.from_message(typestore, msgtype, msg)
        key = (
            id(typestore),
            msgtype,
            lay.size,
            lay.struct_bytes.tobytes(),
            lay.struct_index.tobytes(),
        )
        if key not in self._by_key:
            lay.probe(typestore)
        self._by_key[key] = lay
        return lay


_LAYOUTS = _LayoutCache()


def encode_block(
    msgtype: str, template, values: Mapping, n: int | None = None, typestore=None
) -> np.ndarray:
    """CDR records of ``n`` messages that equal ``template`` (a rosbags message of
    ``msgtype``) except for the numeric fields in ``values`` (leaf path such as
    ``"pose.pose.position.x"`` or ``"velocity"`` -> array of n rows): an (n, size) uint8 array,
    row k byte-identical to ``typestore.serialize_cdr`` of the template with row k's values
    (:meth:`BagWriter.write_many` writes it). Raises :class:`LayoutError`."""
    ts = typestore if typestore is not None else jazzy_typestore()
    if n is None:
        if not values:
            raise LayoutError(f"{msgtype}: encode_block needs n or at least one field")
        n = len(next(iter(values.values())))
    lay = _LAYOUTS.for_message(ts, msgtype, template)
    return lay.encode(int(n), values)


def records_close(
    msgtype: str, a, b, rtol: float = 1e-12, atol: float = 1e-12, typestore=None
) -> bool:
    """Whether two CDR records of ``msgtype`` have the same structure (strings, sequence
    lengths) and numeric fields equal within ``rtol``/``atol`` (integers exactly): the check
    of a block-built record against one serialised from a message builder."""
    ts = typestore if typestore is not None else jazzy_typestore()
    a, b = bytes(a), bytes(b)
    lay = _LAYOUTS.for_record(ts, msgtype, b)
    if lay is None or len(a) != lay.size:
        return a == b
    rows = np.frombuffer(a + b, np.uint8).reshape(2, -1)
    if not lay.matches(rows).all():
        return False
    for path, v in lay.decode(rows).items():
        if v.dtype.kind == "f":
            if not np.allclose(v[0], v[1], rtol=rtol, atol=atol, equal_nan=True):
                return False
        elif not np.array_equal(v[0], v[1]):
            return False
    return True
