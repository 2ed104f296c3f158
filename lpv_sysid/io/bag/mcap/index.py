"""Reading a healthy, indexed mcap bag through its summary and message indexes.

A healthy mcap bag (what :class:`~lpv_sysid.io.bag.writer.BagWriter` and ``ros2 bag
record`` write) is read here without rosbags' Reader: its summary section (schemas,
channels, chunk indexes, statistics) and ``metadata.yaml`` (PyYAML's C loader) are parsed
directly, chunks are decompressed through rosbags' ``decompress`` (size and CRC checked)
and the records of each topic gathered through the message indexes with array indexing
(:func:`_rows_from_index`) or walked in one loop (:func:`_read_fast`); :func:`_topic_info_fast`
reads only the summary and the message indexes. Anything unusual -- no summary,
compression, sqlite3, IDL definitions, topics whose QoS or encoding differ between
``metadata.yaml`` and the file -- raises :class:`_FastPathUnavailable` and the bag is read
by rosbags' AnyReader (:mod:`lpv_sysid.io.bag.reader`), which also names the problem of a
damaged bag. A file that is not a regular file raises
:class:`~lpv_sysid.io.bag.bagfiles.UnsafeBagFile` instead (no reader may open it).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from lpv_sysid.errors import BagError
from lpv_sysid.io.bag.bagfiles import UnsafeBagFile, open_file
from lpv_sysid.io.bag.mcap.records import (
    _MCAP_CHUNK_HEAD,
    _MCAP_FOOTER_HEAD,
    _MCAP_MSG,
    _MCAP_OPLEN,
    MCAP_MAGIC,
    _read_bytes,
    _read_str,
)
from lpv_sysid.io.bag.metadata import _yaml_load, load_metadata
from lpv_sysid.io.bag.records import TopicStats, _Rows, _Source
from lpv_sysid.io.bag.typestore import _definition_ok


class _FastPathUnavailable(Exception):
    """The fast reader does not handle this bag; rosbags' AnyReader reads it instead."""


@dataclass
class _ChunkRef:
    """A ChunkIndex record of the summary (what rosbags' reader relies on)."""

    start: int  # file offset of the Chunk record
    length: int
    index: dict  # channel id -> file offset of its MessageIndex record
    index_length: int
    counts: dict  # channel id -> messages (from the index lengths)
    t0: int = 0  # message start / end time
    t1: int = 0
    compression: str = ""
    csize: int = 0
    usize: int = 0


@dataclass
class _McapSummary:
    path: Path
    schemas: dict = field(default_factory=dict)  # id -> (name, encoding, text)
    channels: dict = field(default_factory=dict)  # id -> (schema id, topic, encoding, qos)
    chunks: list = field(default_factory=list)
    counts: dict | None = None  # statistics: channel id -> messages


def _mcap_summary(path: Path) -> _McapSummary:
    """Summary of an indexed mcap file, checked as rosbags' McapReader checks it."""
    out = _McapSummary(path)
    with open_file(path, path.parent) as fh:
        size = os.fstat(fh.fileno()).st_size
        head = fh.read(17)
        if len(head) < 17 or head[:8] != MCAP_MAGIC or head[8] != 0x01:
            raise _FastPathUnavailable("no mcap header")
        (hlen,) = struct.unpack_from("<Q", head, 9)
        rec = fh.read(hlen)
        profile, _ = _read_str(rec, 0)
        if profile != "ros2":
            raise _FastPathUnavailable(f"mcap profile {profile!r}")
        data_start = 17 + hlen
        if size < data_start + 37:
            raise _FastPathUnavailable("no footer")
        fh.seek(size - 37)
        foot = fh.read(37)
        if foot[-8:] != MCAP_MAGIC or foot[:9] != _MCAP_FOOTER_HEAD:
            raise _FastPathUnavailable("invalid footer")
        (summary_start,) = struct.unpack_from("<Q", foot, 9)
        if not summary_start or not data_start <= summary_start <= size - 37:
            raise _FastPathUnavailable("no summary section")
        fh.seek(summary_start)
        summary = fh.read(size - 37 - summary_start)
    pos = 0
    try:
        while pos < len(summary):
            op, length = _MCAP_OPLEN.unpack_from(summary, pos)
            body = summary[pos + 9 : pos + 9 + length]
            if len(body) != length:
                raise _FastPathUnavailable("truncated summary record")
            pos += 9 + length
            if op in (0x02, 0x0E):
                break
            if op == 0x03:
                (sid,) = struct.unpack_from("<H", body, 0)
                name, p = _read_str(body, 2)
                enc, p = _read_str(body, p)
                text, _ = _read_bytes(body, p)
                out.schemas[sid] = (name, enc, text.decode("utf-8"))
            elif op == 0x04:
                cid, sid = struct.unpack_from("<HH", body, 0)
                topic, p = _read_str(body, 4)
                enc, p = _read_str(body, p)
                meta, _ = _read_bytes(body, p)
                out.channels[cid] = (sid, topic, enc, _channel_qos(meta))
            elif op == 0x08:
                t0, t1, start, clen = struct.unpack_from("<QQQQ", body, 0)
                (n,) = struct.unpack_from("<I", body, 32)
                index = dict(struct.iter_unpack("<HQ", body[36 : 36 + n]))
                (ilen,) = struct.unpack_from("<Q", body, 36 + n)
                comp, p = _read_str(body, 44 + n)
                csize, usize = struct.unpack_from("<QQ", body, p)
                ends = sorted(index.values()) + [start + clen + ilen]
                byoff = {off: cid for cid, off in index.items()}
                counts = {byoff[a]: (b - a - 15) // 16 for a, b in zip(ends, ends[1:])}
                out.chunks.append(
                    _ChunkRef(start, clen, index, ilen, counts, t0, t1, comp, csize, usize)
                )
            elif op == 0x0B:
                (n,) = struct.unpack_from("<I", body, 42)
                out.counts = dict(struct.iter_unpack("<HQ", body[46 : 46 + n]))
    except (struct.error, UnicodeDecodeError, KeyError) as exc:
        raise _FastPathUnavailable(f"summary unreadable: {exc}") from None
    if not out.chunks:
        raise _FastPathUnavailable("no chunk index")
    out.chunks.sort(key=lambda c: c.start)
    return out


def _channel_qos(meta: bytes):
    """The offered QoS profiles of an mcap channel's metadata map, as loaded YAML."""
    pos, items = 0, {}
    while pos < len(meta):
        k, pos = _read_str(meta, pos)
        v, pos = _read_str(meta, pos)
        items[k] = v
    text = items.get("offered_qos_profiles", "")
    return _yaml_load(text) if text else []


@dataclass
class _FastBag:
    types: dict = field(default_factory=dict)  # topic -> msgtype
    msgdefs: dict = field(default_factory=dict)  # msgtype -> ros2msg text
    files: list = field(default_factory=list)  # [(_McapSummary, {channel id: topic})]


def _open_fast(target: Path) -> _FastBag:
    """The topics and indexed mcap files of a healthy bag directory or ``.mcap`` file."""
    bag = _FastBag()
    digests: dict = {}
    if target.is_dir():
        try:
            info = load_metadata(target)
            if info["version"] > 9 or info["storage_identifier"] != "mcap":
                raise _FastPathUnavailable("not a version <= 9 mcap bag")
            if info.get("compression_format") or (
                info.get("compression_mode") or ""
            ).lower() not in ("", "none"):
                raise _FastPathUnavailable("compressed bag")
            files = [target / Path(p).name for p in info["relative_file_paths"]]
            wanted = {}
            for t in info["topics_with_message_count"]:
                tm = t["topic_metadata"]
                qos = tm.get("offered_qos_profiles", [])
                qos = _yaml_load(qos) if isinstance(qos, str) else qos
                if tm["name"] in wanted or tm["serialization_format"] != "cdr":
                    raise _FastPathUnavailable("duplicate or non-CDR topic")
                wanted[tm["name"]] = (tm["type"], qos or [])
                digests[tm["type"]] = tm.get("type_description_hash", "") or ""
        except UnsafeBagFile:
            raise
        except (BagError, OSError, yaml.YAMLError, KeyError, TypeError, AttributeError) as exc:
            raise _FastPathUnavailable(f"metadata.yaml: {exc}") from None
        summaries = [_mcap_summary(f) for f in files]
        for name, (typ, _qos) in wanted.items():
            bag.types[name] = typ
        for sm in summaries:
            cmap = {}
            for cid, (sid, topic, enc, qos) in sm.channels.items():
                if topic not in wanted:
                    continue
                typ = sm.schemas.get(sid, ("__schemaless__",))[0]
                if typ != wanted[topic][0]:
                    continue
                if enc != "cdr" or qos != wanted[topic][1]:
                    raise _FastPathUnavailable(
                        f"{topic}: QoS or encoding differ from metadata.yaml"
                    )
                cmap[cid] = topic
            bag.files.append((sm, cmap))
    elif target.suffix == ".mcap":
        sm = _mcap_summary(target)
        cmap = {}
        for cid, (sid, topic, enc, _qos) in sm.channels.items():
            if topic in bag.types or enc != "cdr":
                raise _FastPathUnavailable("duplicate or non-CDR topic")
            bag.types[topic] = sm.schemas.get(sid, ("__schemaless__",))[0]
            cmap[cid] = topic
        bag.files.append((sm, cmap))
    else:
        raise _FastPathUnavailable("not an mcap bag")
    for sm, _ in bag.files:
        for sid, (name, enc, text) in sm.schemas.items():
            if enc == "ros2idl":
                raise _FastPathUnavailable("IDL definitions")
            if enc == "ros2msg" and text and name in set(bag.types.values()):
                bag.msgdefs.setdefault(name, text)
    for msgtype, text in bag.msgdefs.items():  # AnyReader's definition and hash check
        if not _definition_ok(msgtype, text, digests.get(msgtype, "")):
            raise _FastPathUnavailable(f"{msgtype}: definition does not match its hash")
    return bag


def _read_fast(target: Path, topics: set | None, src: _Source) -> None:
    """Raw records of a healthy mcap bag into ``src`` (what ``_read_with_rosbags`` collects
    through AnyReader); raises :class:`_FastPathUnavailable` otherwise."""
    bag = _open_fast(target)
    src.types.update(bag.types)
    src.msgdefs.update(bag.msgdefs)
    for sm, cmap in bag.files:
        sel = {cid: t for cid, t in cmap.items() if topics is None or t in topics}
        if sel:
            _mcap_chunk_records(sm, sel, src.records)


def _chunk_payload(fh, ch: _ChunkRef) -> bytes:
    """Decompressed records of one chunk (size and CRC checked by rosbags' decompress)."""
    from rosbags.rosbag2.storage_mcap import decompress

    fh.seek(ch.start)
    rec = fh.read(ch.length)
    if len(rec) != ch.length or rec[0] != 0x06:
        raise _FastPathUnavailable(f"chunk at {ch.start} unreadable")
    t0, t1, usize, crc = _MCAP_CHUNK_HEAD.unpack_from(rec, 9)
    comp, p = _read_str(rec, 37)
    (csize,) = struct.unpack_from("<Q", rec, p)
    if p + 8 + csize > len(rec):
        raise _FastPathUnavailable("chunk data beyond its record")
    if (t0, t1, usize, comp, csize) != (ch.t0, ch.t1, ch.usize, ch.compression, ch.csize):
        raise _FastPathUnavailable(f"chunk at {ch.start} disagrees with its index")
    return decompress(rec[p + 8 : p + 8 + csize], comp, usize, crc)


def _mcap_chunk_records(sm: _McapSummary, cmap: dict, out: list) -> None:
    """Message records of the channels in ``cmap`` (channel id -> topic), every chunk of
    the file, appended to ``out`` as (topic, log_time, data)."""
    oplen, msg_hdr = _MCAP_OPLEN.unpack_from, _MCAP_MSG.unpack_from
    append = out.append
    with open_file(sm.path, sm.path.parent) as fh:
        for ch in sm.chunks:
            if ch.counts and not any(ch.counts.get(cid) for cid in cmap):
                continue
            buf = _chunk_payload(fh, ch)
            view = memoryview(buf)
            pos, n = 0, len(buf)
            while pos < n:
                op, length = oplen(buf, pos)
                end = pos + 9 + length
                if end > n:
                    raise _FastPathUnavailable("record beyond its chunk")
                if op == 0x05:
                    if length < 22:
                        raise _FastPathUnavailable("short message record")
                    cid, _seq, log_time = msg_hdr(buf, pos + 9)
                    topic = cmap.get(cid)
                    if topic is not None:
                        if not ch.t0 <= log_time <= ch.t1:  # rosbags would drop it
                            raise _FastPathUnavailable("message time outside its chunk")
                        append((topic, log_time, view[pos + 31 : end]))
                pos = end


def _topic_info_fast(path: Path) -> dict[str, TopicStats]:
    """topic_info of a healthy indexed mcap bag from its summary and message indexes
    (16 bytes per message; nothing is decompressed)."""
    bag = _open_fast(path)
    stats: dict[str, list] = {t: [0, None, None] for t in bag.types}
    for sm, cmap in bag.files:
        seen: dict[int, int] = {}
        with open_file(sm.path, sm.path.parent) as fh:
            for ch in sm.chunks:
                for cid, off in ch.index.items():
                    topic = cmap.get(cid)
                    if topic is None:
                        continue
                    fh.seek(off)
                    head = fh.read(15)
                    if len(head) != 15 or head[0] != 0x07:
                        raise _FastPathUnavailable(f"message index at {off} unreadable")
                    (length,) = struct.unpack_from("<Q", head, 1)
                    rcid, nbytes = struct.unpack_from("<HI", head, 9)
                    if rcid != cid or nbytes % 16 or 6 + nbytes > length:
                        raise _FastPathUnavailable(f"message index at {off} inconsistent")
                    if not nbytes:
                        continue
                    times = np.frombuffer(fh.read(nbytes), "<u8")
                    if times.size * 8 != nbytes:
                        raise _FastPathUnavailable(f"message index at {off} truncated")
                    times = times[0::2]
                    s = stats[topic]
                    lo, hi = int(times.min()), int(times.max())
                    s[0] += int(times.size)
                    seen[cid] = seen.get(cid, 0) + int(times.size)
                    s[1] = lo if s[1] is None else min(s[1], lo)
                    s[2] = hi if s[2] is None else max(s[2], hi)
        if sm.counts is not None and any(
            sm.counts.get(cid, 0) != seen.get(cid, 0) for cid in cmap
        ):
            raise _FastPathUnavailable("message indexes disagree with the statistics")
    return {t: TopicStats(bag.types[t], *s) for t, s in sorted(stats.items())}


def _rows_from_index(bag: _FastBag, topics) -> dict[str, _Rows]:
    """Records of the selected topics of a healthy mcap bag, gathered chunk by chunk through
    the message indexes with array indexing (no per-record Python work)."""
    rows: dict[str, _Rows] = {}
    for fno, (sm, cmap) in enumerate(bag.files):
        sel = {cid: t for cid, t in cmap.items() if topics is None or t in topics}
        if not sel:
            continue
        with open_file(sm.path, sm.path.parent) as fh:
            for cno, ch in enumerate(sm.chunks):
                cids = [cid for cid in sel if ch.counts.get(cid)]
                if not cids:
                    continue
                if any(cid not in ch.index for cid in cids):
                    raise _FastPathUnavailable("chunk without message index")
                payload = np.frombuffer(_chunk_payload(fh, ch), np.uint8)
                fh.seek(ch.start + ch.length)
                index = fh.read(ch.index_length)
                base = ch.start + ch.length
                for cid in cids:
                    off = ch.index[cid] - base
                    if off < 0 or off + 15 > len(index) or index[off] != 0x07:
                        raise _FastPathUnavailable("message index unreadable")
                    (nbytes,) = struct.unpack_from("<I", index, off + 11)
                    ent = np.frombuffer(index, "<u8", nbytes // 8, off + 15).reshape(-1, 2)
                    times, offs = ent[:, 0].astype(np.int64), ent[:, 1].astype(np.int64)
                    if offs.size and (
                        offs.max() + 31 > payload.size or np.any(payload[offs] != 0x05)
                    ):
                        raise _FastPathUnavailable("message index does not point at messages")
                    rec_len = payload[offs[:, None] + np.arange(1, 9)].copy().view("<u8")[:, 0]
                    ids = payload[offs[:, None] + np.arange(9, 11)].copy().view("<u2")[:, 0]
                    rec_t = payload[offs[:, None] + np.arange(15, 23)].copy().view("<u8")[:, 0]
                    if (
                        np.any(ids != cid)
                        or np.any(rec_len < 22)
                        or np.any(offs + 9 + rec_len.astype(np.int64) > payload.size)
                        or np.any(rec_t != ent[:, 0])
                        or np.any(rec_t < ch.t0)
                        or np.any(rec_t > ch.t1)
                    ):
                        raise _FastPathUnavailable("message index inconsistent")
                    lens = rec_len.astype(np.int64) - 22
                    order = (np.int64(fno) << 56) | (np.int64(cno) << 32) | offs
                    r = rows.setdefault(sel[cid], _Rows())
                    for n in np.unique(lens).tolist():
                        k = lens == n
                        start = offs[k] + 31
                        block = (
                            np.lib.stride_tricks.sliding_window_view(payload, n)[start]
                            if n
                            else np.zeros((int(k.sum()), 0), np.uint8)
                        )
                        r.blocks.setdefault(n, []).append((times[k], order[k], block))
    return rows
