"""Reading a bag column-wise: :func:`read_arrays` (``{topic: TopicArrays}``).

The fixed-layout records this package writes are decoded per topic as numpy blocks (the
CDR block codec, :mod:`lpv_sysid.io.bag.cdr.layout`); other records go through rosbags'
``deserialize_cdr``. Values are those of rosbags' ``deserialize_cdr`` of the same records
(checked in test_bag_codec.py), in the order of :func:`~lpv_sysid.io.bag.reader.read_bag`.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Iterable

import numpy as np

from lpv_sysid.errors import BagError
from lpv_sysid.io.bag.bagfiles import UnsafeBagFile
from lpv_sysid.io.bag.cdr import CdrLayout
from lpv_sysid.io.bag.cdr.layout import _LAYOUTS, _MAX_LAYOUT_GROUPS, _get_path, _LayoutWalk
from lpv_sysid.io.bag.collect import _collect
from lpv_sysid.io.bag.durability import _describe
from lpv_sysid.io.bag.mcap.index import _open_fast, _rows_from_index
from lpv_sysid.io.bag.records import BagArrays, TopicArrays, _Rows, _Source
from lpv_sysid.io.bag.typestore import _deserializers

LOG = logging.getLogger(__name__)


def _rows_from_sources(sources: list) -> dict[str, _Rows]:
    rows: dict[str, _Rows] = {}
    k = 0
    for src in sources:
        for topic, ns, data in src.records:
            rows.setdefault(topic, _Rows()).add_bytes(ns, k, data)
            k += 1
    return rows


class _Decoded:
    """Per-group decoding result of one topic: layouts with their rows, plus odd rows."""

    def __init__(self) -> None:
        self.parts: list = []  # (times, order, layout, fields dict) per layout group
        self.odd: list = []  # (time, order, bytes) for rosbags


def _decode_rows(store, msgtype: str, rows: _Rows) -> _Decoded:
    out = _Decoded()
    for times, order, block in rows.groups():
        rest = np.arange(block.shape[0])
        groups = 0
        while rest.size and groups < _MAX_LAYOUT_GROUPS:
            try:
                lay = _LAYOUTS.for_record(store, msgtype, block[rest[0]].tobytes())
            except Exception:  # noqa: BLE001 - rosbags cannot read it: leave it to the caller
                lay = None
            if lay is None:
                break
            hit = lay.matches(block[rest])
            take = rest[hit]
            out.parts.append((times[take], order[take], lay, lay.decode(block[take])))
            rest = rest[~hit]
            groups += 1
        for i in rest.tolist():
            out.odd.append((int(times[i]), int(order[i]), block[i].tobytes()))
    return out


def _leaf_values(store, msgtype: str, msg) -> tuple[dict, dict]:
    """Numeric leaves and strings of one deserialised message, by path (odd records)."""
    acc = _LayoutWalk()
    CdrLayout._walk(store, msgtype, msg, 0, "", acc)
    strings = acc.strings
    vals = {}
    for lf in acc.leaves:
        v = _get_path(msg, lf.path)
        vals[lf.path] = np.asarray(v, dtype=lf.dtype) if lf.count is not None else v
    return vals, strings


def read_arrays(
    path, topics: Iterable[str] | None = None, strict: bool = True, optional: Iterable[str] = ()
) -> BagArrays:
    """Read a bag column-wise: ``{topic: TopicArrays}`` (arguments as :func:`read_bag`).

    The fixed-layout records this package writes are decoded per topic as numpy blocks (see
    the CDR block codec above); other records go through rosbags' ``deserialize_cdr``.
    A topic whose messages differ in structure (e.g. sequence lengths, so that a field has no
    common shape) raises :class:`BagError` (``strict=False``: listed in ``problems`` and left
    out). Orders of magnitude faster than :func:`read_bag` for long recordings.
    """
    optional = [t for t in optional if topics is None or t not in topics]
    want_list = None if topics is None else list(topics)
    want = None if want_list is None else set(want_list) | set(optional)
    p = Path(path)
    out = BagArrays()
    sources: list[_Source] = []
    types: dict[str, str]
    msgdefs: dict[str, str]
    try:
        bag = _open_fast(p)
        rows = _rows_from_index(bag, want)
        types = dict(bag.types)
        msgdefs = dict(bag.msgdefs)
    except Exception as exc:  # noqa: BLE001 - the record-level reader decides
        if strict and isinstance(exc, UnsafeBagFile):
            raise
        LOG.debug("bag %s: index gather not used (%s)", p, _describe(exc))
        sources, out.problems = _collect(p, None if want is None else list(want), strict)
        rows = _rows_from_sources(sources)
        types, msgdefs = {}, {}
        for src in sources:
            for t, ty in src.types.items():
                types.setdefault(t, ty)
            for ty, text in src.msgdefs.items():
                msgdefs.setdefault(ty, text)
    src = _Source()
    src.types, src.msgdefs = types, msgdefs
    stores = _deserializers([src])
    for topic, msgtype in types.items():
        if want is None or topic in want:
            out.types[topic] = msgtype
    if want_list is not None:
        missing = [t for t in want_list if t not in out.types]
        if missing:
            msg = f"bag {path}: topic(s) {missing} not in bag; it has {sorted(types)}"
            if strict:
                raise BagError(msg)
            out.problems.append(msg)
    for topic, msgtype in out.types.items():
        store = stores.get(msgtype)
        r = rows.get(topic, _Rows())
        try:
            if store is None:
                if r.blocks or r.raw:
                    raise BagError(f"bag {path}: topic {topic!r}: no definition for {msgtype}")
                out[topic] = TopicArrays(msgtype, np.zeros(0, np.int64), {}, {})
                continue
            out[topic] = _topic_arrays(path, topic, msgtype, store, r, strict, out.problems)
        except BagError as exc:
            if strict:
                raise
            out.problems.append(str(exc))
    for p_ in out.problems:
        LOG.warning("%s", p_)
    return out


def _topic_arrays(path, topic, msgtype, store, rows: _Rows, strict, problems) -> TopicArrays:
    dec = _decode_rows(store, msgtype, rows)
    parts = [(t, o, lay.leaves, f, lay.strings) for t, o, lay, f in dec.parts]
    bad = 0
    for t, o, data in dec.odd:
        try:
            msg = store.deserialize_cdr(data, msgtype)
        except Exception as exc:  # noqa: BLE001
            if strict:
                raise BagError(
                    f"bag {path}: topic {topic!r}: message at {t} ns cannot be "
                    f"deserialised as {msgtype}: {_describe(exc)}"
                ) from None
            bad += 1
            continue
        vals, strings = _leaf_values(store, msgtype, msg)
        f = {
            k: (np.asarray(v)[None] if not isinstance(v, np.ndarray) else v[None])
            for k, v in vals.items()
        }
        parts.append((np.array([t], np.int64), np.array([o], np.int64), None, f, strings))
    if bad:
        problems.append(f"bag {path}: topic {topic!r}: {bad} message(s) could not be deserialised")
    if not parts:
        return TopicArrays(msgtype, np.zeros(0, np.int64), {}, {})
    keys = [
        (tuple(sorted((k, v.shape[1:]) for k, v in f.items())), tuple(sorted(s)))
        for _, _, _, f, s in parts
    ]
    if any(k != keys[0] for k in keys):
        raise BagError(
            f"bag {path}: topic {topic!r}: messages of different structure (sequence "
            "lengths or fields differ); read it with read_bag()"
        )
    times = np.concatenate([pt[0] for pt in parts])
    order = np.concatenate([pt[1] for pt in parts])
    idx = np.lexsort((order, times))
    if len(parts) == 1 and np.array_equal(idx, np.arange(idx.size)):
        idx = slice(None)  # already in order: no copy
    fields_ = {
        k: (np.concatenate([pt[3][k] for pt in parts]) if len(parts) > 1 else parts[0][3][k])[idx]
        for k in parts[0][3]
    }
    strings = {}
    for k in parts[0][4]:
        col = np.empty(times.size, dtype=object)
        pos = 0
        for pt in parts:
            n = pt[0].size
            col[pos : pos + n].fill(pt[4][k])
            pos += n
        strings[k] = col[idx]
    return TopicArrays(msgtype, times[idx], fields_, strings)


_BUILDERS: dict = {}
