"""In-place repair of one mcap storage file (``lpv-sysid bag repair``).

The incomplete tail (a record the process did not finish) is cut -- the complete records of
a chunk the cut went through are written again as a chunk of their own (with its CRC), so
no complete record is dropped -- the message index of the last chunk regenerated if it was
cut, the chunk a failed writer still held in memory appended, and a summary section
(schemas, channels, chunk indexes, statistics) and footer written after it -- nothing
before the cut is rewritten, so a repair needs only a few kB even on a full disk -- then
rosbags' own reader checks the result. The file is found by the salvage walk of
:mod:`lpv_sysid.io.bag.mcap.walk`.
"""

from __future__ import annotations

import contextlib
import os
import struct
from pathlib import Path

from lpv_sysid.errors import BagError
from lpv_sysid.io.bag.bagfiles import open_file
from lpv_sysid.io.bag.durability import _describe
from lpv_sysid.io.bag.mcap.records import MCAP_MAGIC, _enc_str, _record, chunk_crc
from lpv_sysid.io.bag.mcap.walk import _Chunk, _Damaged, _McapWalk, _walk_mcap, _walk_records
from lpv_sysid.io.bag.records import TopicStats, _add_stats, _FileInfo
from lpv_sysid.io.bag.typestore import _rihs01


def _mcap_info(f: Path, walk: _McapWalk, chunks, changed: bool, cut: int, notes) -> _FileInfo:
    from rosbags.rosbag2.storage_mcap import get_qos

    counts: dict[int, int] = {}
    spans: dict[int, tuple[int, int]] = {}
    nbytes = 0
    for ch in chunks:
        for cid, entries in ch.msgs.items():
            if not entries:
                continue
            counts[cid] = counts.get(cid, 0) + len(entries)
            lo = min(t for t, _ in entries)
            hi = max(t for t, _ in entries)
            a, b = spans.get(cid, (lo, hi))
            spans[cid] = (min(a, lo), max(b, hi))
            nbytes += ch.nbytes.get(cid, 0)
    conns: list[tuple] = []
    topics: dict[str, TopicStats] = {}
    for cid, (sid, topic, enc, meta) in sorted(walk.channels.items()):
        if sid not in walk.schemas:
            notes.append(f"{f.name}: channel {topic} has no schema; left out")
            continue
        name, senc, text = walk.schemas[sid]
        n = counts.get(cid, 0)
        try:
            qos = get_qos(meta)
        except Exception:  # noqa: BLE001
            qos = []
        conns.append((topic, name, enc, qos, _rihs01(name, senc, text), n))
        span = spans.get(cid)
        topics[topic] = _add_stats(topics.get(topic), TopicStats(name, n, *(span or (None, None))))
    return _FileInfo(f.name, conns, topics, nbytes, changed, cut, list(notes))


def _index_records(chunk: _Chunk, base: int) -> bytes:
    """MessageIndex records of ``chunk``, placed at file offset ``base``; sets its index."""
    out = bytearray()
    chunk.index = {}
    for cid, entries in chunk.msgs.items():
        if not entries:
            continue
        chunk.index[cid] = base + len(out)
        body = struct.pack("<HI", cid, 16 * len(entries)) + b"".join(
            struct.pack("<QQ", t, off) for t, off in entries
        )
        out += _record(0x07, body)
    chunk.index_end = base + len(out)
    return bytes(out)


def _summary(walk: _McapWalk, chunks, base: int) -> bytes:
    """DataEnd, summary section (schemas, channels, chunk indexes, statistics, summary
    offsets) and footer + magic, to be written at file offset ``base``."""
    out = bytearray(_record(0x0F, struct.pack("<I", 0)))
    summary_start = base + len(out)
    groups = []
    start = len(out)
    for sid, (name, enc, data) in sorted(walk.schemas.items()):
        raw = data.encode("utf-8")
        out += _record(
            0x03,
            struct.pack("<H", sid)
            + _enc_str(name)
            + _enc_str(enc)
            + struct.pack("<I", len(raw))
            + raw,
        )
    groups.append((0x03, start, len(out)))
    start = len(out)
    for cid, (sid, topic, enc, meta) in sorted(walk.channels.items()):
        out += _record(
            0x04,
            struct.pack("<HH", cid, sid)
            + _enc_str(topic)
            + _enc_str(enc)
            + struct.pack("<I", len(meta))
            + meta,
        )
    groups.append((0x04, start, len(out)))
    start = len(out)
    counts: dict = {}
    t_lo, t_hi = None, None
    for ch in chunks:
        offsets = b"".join(
            struct.pack("<HQ", cid, off)
            for cid, off in sorted(ch.index.items(), key=lambda kv: kv[1])
        )
        out += _record(
            0x08,
            struct.pack("<QQQQ", ch.t0, ch.t1, ch.start, ch.length)
            + struct.pack("<I", len(offsets))
            + offsets
            + struct.pack("<Q", ch.index_end - ch.end)
            + _enc_str(ch.compression)
            + struct.pack("<QQ", ch.csize, ch.usize),
        )
        for cid, entries in ch.msgs.items():
            if entries:
                counts[cid] = counts.get(cid, 0) + len(entries)
                lo, hi = min(t for t, _ in entries), max(t for t, _ in entries)
                t_lo = lo if t_lo is None else min(t_lo, lo)
                t_hi = hi if t_hi is None else max(t_hi, hi)
    groups.append((0x08, start, len(out)))
    start = len(out)
    stats = b"".join(struct.pack("<HQ", cid, n) for cid, n in sorted(counts.items()))
    out += _record(
        0x0B,
        struct.pack(
            "<QHIIIIQQ",
            sum(counts.values()),
            len(walk.schemas),
            len(walk.channels),
            0,
            walk.metadata_records,
            len(chunks),
            t_lo or 0,
            t_hi or 0,
        )
        + struct.pack("<I", len(stats))
        + stats,
    )
    groups.append((0x0B, start, len(out)))
    offsets_start = base + len(out)
    for op, a, b in groups:
        if b > a:
            out += _record(0x0E, struct.pack("<BQQ", op, base + a, b - a))
    out += _record(0x02, struct.pack("<QQI", summary_start, offsets_start, 0)) + MCAP_MAGIC
    return bytes(out)


def _empty_mcap_head() -> bytes:
    from importlib.metadata import version

    return MCAP_MAGIC + _record(0x01, _enc_str("ros2") + _enc_str(f"rosbags-{version('rosbags')}"))


def _repair_mcap_file(
    f: Path, dry_run: bool, limit: int | None, pending: tuple[bytes, int, int] | None
) -> _FileInfo:
    from rosbags.rosbag2.storage_mcap import McapReader

    if limit is None and pending is None:
        reader = McapReader(f)
        try:
            reader.open()
        except Exception:  # noqa: BLE001 - not a complete file: repair below
            pass
        else:
            reader.close()
            walk = _walk_mcap(f)
            return _mcap_info(f, walk, walk.chunks, False, 0, [])
    walk = _walk_mcap(f, limit=limit)
    notes: list[str] = []
    head = b""
    if walk.header_ok:
        base = walk.data_end
    else:
        with open_file(f, f.parent) as fh:
            first = fh.read(64)
        sig = MCAP_MAGIC + b"\x01"
        if walk.size >= 64 or first[: len(sig)] != sig[: len(first)]:
            raise BagError(f"bag {f.parent}: {walk.problems[0]}; not repaired")
        head = _empty_mcap_head()  # killed before its header reached the disk
        base = len(head)
        notes.append(f"{f.name}: no complete header; rewritten as an empty mcap")
    chunks = list(walk.chunks)
    old_tail = b""
    if chunks and not chunks[-1].index_complete():
        base = chunks[-1].end  # cut its partial message index, write it anew
        old_tail = _index_records(chunks[-1], base)
    for ch in chunks[:-1]:
        if not ch.index_complete():
            notes.append(
                f"{f.name}: chunk at byte {ch.start} has no complete message index; "
                "left out of the index"
            )
    indexed = [ch for ch in chunks if ch.index_complete()]
    if walk.unchunked:
        notes.append(f"{f.name}: {walk.unchunked} message(s) outside chunks are not indexed")
    new_tail, extra = b"", []
    rechunk: list[tuple[bytes, dict, dict, int, int]] = []
    if walk.partial is not None:
        # the complete records of the chunk the cut went through: never dropped
        _at, data, msgs, nbytes = walk.partial
        times = [t for entries in msgs.values() for t, _ in entries]
        if data:  # also Schema/Channel records alone: the data section keeps the channels
            rechunk.append((data, msgs, nbytes, min(times, default=0), max(times, default=0)))
            n = len(times)
            notes.append(f"{f.name}: {n} complete message(s) of the cut chunk kept (re-chunked)")
    if pending is not None:
        data, t0, t1 = pending
        try:
            msgs, nbytes = _walk_records(data, walk, None, f"{f.name}: chunk held in memory")
        except _Damaged as exc:
            notes.append(str(exc))
        else:
            rechunk.append((data, msgs, nbytes, t0, t1))
    at = base + len(old_tail)
    for data, msgs, nbytes, t0, t1 in rechunk:
        rec, ch = _chunk_record(data, msgs, nbytes, t0, t1, at)
        new_tail += rec
        extra.append(ch)
        at += len(rec)
    cut = max(0, walk.size - base) if walk.header_ok else walk.size
    if dry_run:
        return _mcap_info(f, walk, indexed + extra, True, cut, notes + walk.problems[:1])
    try:
        tail = old_tail + new_tail
        _write_tail(f, head, base, tail + _summary(walk, indexed + extra, base + len(tail)))
    except OSError as exc:
        if not extra:
            raise BagError(
                f"bag {f.parent}: cannot write the index of {f.name}: {_describe(exc)}"
            ) from None
        lost = sum(len(v) for ch in extra for v in ch.msgs.values())
        notes.append(f"{f.name}: no room for the last {lost} message(s) ({_describe(exc)})")
        extra = []
        try:
            _write_tail(f, head, base, old_tail + _summary(walk, indexed, base + len(old_tail)))
        except OSError as exc2:
            raise BagError(
                f"bag {f.parent}: cannot write the index of {f.name}: {_describe(exc2)}"
            ) from None
    info = _mcap_info(f, walk, indexed + extra, True, cut, notes)
    reader = McapReader(f)
    try:
        reader.open()
        got = reader.metadata.message_count
    except Exception as exc:  # noqa: BLE001
        raise BagError(
            f"bag {f.parent}: {f.name} fails rosbags' check after repair: {_describe(exc)}"
        ) from None
    finally:
        with contextlib.suppress(Exception):
            reader.close()
    if got != info.count:
        raise BagError(
            f"bag {f.parent}: {f.name} after repair: rosbags counts {got} "
            f"messages, the index {info.count}"
        )
    return info


def _chunk_record(
    data: bytes, msgs: dict, nbytes: dict, t0: int, t1: int, at: int
) -> tuple[bytes, _Chunk]:
    """An uncompressed Chunk record of the records ``data`` (with its CRC) and its
    MessageIndex records, to be written at file offset ``at``; and its :class:`_Chunk`."""
    body = (
        struct.pack("<QQQI", t0, t1, len(data), chunk_crc(data))
        + _enc_str("")
        + struct.pack("<Q", len(data))
        + data
    )
    n = 9 + len(body)
    ch = _Chunk(at, n, t0, t1, len(data), len(data), "", msgs, nbytes, {}, at + n)
    return _record(0x06, body) + _index_records(ch, ch.end), ch


def _write_tail(f: Path, head: bytes, base: int, tail: bytes) -> None:
    """Cut ``f`` at ``base`` and append ``tail`` (``head`` replaces a missing header);
    on failure the file is cut back to ``base`` (what was kept stays, ready for a retry)."""
    with open_file(f, f.parent, writable=True) as fh:
        if head:
            fh.truncate(0)
            fh.write(head)
        fh.truncate(base)
        fh.seek(base)
        try:
            fh.write(tail)
            fh.flush()
            os.fsync(fh.fileno())
        except OSError:
            with contextlib.suppress(OSError):
                fh.truncate(base)
            raise
