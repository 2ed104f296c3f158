"""Record-level walk of an mcap file that may be unfinished (the salvage parser).

MCAP records are (opcode u8, length u64, body). rosbags 0.11.9 writes: magic, Header,
then Chunks (its first chunk also holds the Schema and Channel records), each followed by
one MessageIndex per channel, and at close Metadata, DataEnd, the summary section and the
Footer. A killed or starved writer leaves the file cut anywhere after a chunk.

Why this parser is written here: rosbags' ``McapReader`` refuses any file without a valid
footer (it seeks the footer and the summary first), so it cannot read the complete
records of a recording whose writer was killed, and the reference ``mcap`` library is not
a dependency (requirements.txt). :func:`_walk_mcap` walks the data section from the start,
record by record, and stops at the first incomplete or unreadable record; it feeds
:func:`_salvage_mcap` (``read_bag(strict=False)``) and the in-place repair
(:mod:`lpv_sysid.io.bag.mcap.repair`), after which rosbags reads the file itself.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

from lpv_sysid.io.bag.bagfiles import open_file
from lpv_sysid.io.bag.durability import _describe
from lpv_sysid.io.bag.mcap.records import MCAP_MAGIC, _read_bytes, _read_str, _record
from lpv_sysid.io.bag.records import _Source

#: ``on_message(channel_id, log_time, data)``
OnMessage = Optional[Callable[[int, int, bytes], None]]

_DATA_OPS = frozenset({0x03, 0x04, 0x05, 0x06, 0x07, 0x09, 0x0C})
_END_OPS = frozenset({0x02, 0x08, 0x0A, 0x0B, 0x0D, 0x0E, 0x0F})  # footer / summary / data end


class _Damaged(Exception):
    """A record that cannot be parsed; ends the walk."""


@dataclass
class _Chunk:
    """A complete Chunk record found in (or appended to) an mcap file."""

    start: int  # file offset of the record
    length: int  # record length including opcode and length field
    t0: int
    t1: int
    usize: int
    csize: int
    compression: str
    msgs: dict  # channel id -> [(log_time, offset in the records)]
    nbytes: dict  # channel id -> payload bytes
    index: dict = field(default_factory=dict)  # channel id -> file offset of its MessageIndex
    index_end: int = 0

    @property
    def end(self) -> int:
        return self.start + self.length

    def index_complete(self) -> bool:
        return set(self.index) == {c for c, v in self.msgs.items() if v}


@dataclass
class _McapWalk:
    schemas: dict = field(default_factory=dict)  # id -> (name, encoding, data)
    channels: dict = field(default_factory=dict)  # id -> (schema id, topic, encoding, metadata)
    chunks: list = field(default_factory=list)
    metadata_records: int = 0
    unchunked: int = 0
    header_ok: bool = False
    data_start: int = 0
    data_end: int = 0  # offset after the last complete data record
    size: int = 0  # file size
    ended: bool = False  # reached data end / summary / footer
    problems: list = field(default_factory=list)
    #: the complete records of a Chunk cut by the end of the file (uncompressed chunks):
    #: (file offset of the cut chunk, their bytes, msgs, nbytes); the repair re-chunks them
    partial: Optional[tuple[int, bytes, dict, dict]] = None


def _parse_schema(buf, pos: int, walk: _McapWalk) -> None:
    (sid,) = struct.unpack_from("<H", buf, pos)
    name, p = _read_str(buf, pos + 2)
    enc, p = _read_str(buf, p)
    data, _ = _read_bytes(buf, p)
    walk.schemas[sid] = (name, enc, data.decode("utf-8"))


def _parse_channel(buf, pos: int, walk: _McapWalk) -> None:
    cid, sid = struct.unpack_from("<HH", buf, pos)
    topic, p = _read_str(buf, pos + 4)
    enc, p = _read_str(buf, p)
    meta, _ = _read_bytes(buf, p)
    walk.channels[cid] = (sid, topic, enc, meta)


def _walk_records(
    buf, walk: _McapWalk, on_message: OnMessage, where: str
) -> tuple[dict[int, list], dict[int, int]]:
    """The records inside a chunk: Schema/Channel update ``walk``; Message records go to
    ``on_message(channel_id, log_time, data)``. Returns ``(msgs, nbytes)`` per channel."""
    msgs: dict[int, list] = {}
    nbytes: dict[int, int] = {}
    pos, n = 0, len(buf)
    while pos < n:
        if pos + 9 > n:
            raise _Damaged(f"{where}: truncated record header at byte {pos}")
        op = buf[pos]
        (length,) = struct.unpack_from("<Q", buf, pos + 1)
        body, end = pos + 9, pos + 9 + length
        if end > n:
            raise _Damaged(
                f"{where}: truncated record (op 0x{op:02x}) at byte {pos}: "
                f"{n - body} of {length} bytes present"
            )
        try:
            if op == 0x05:
                if length < 22:
                    raise _Damaged(f"{where}: message record of {length} bytes at byte {pos}")
                cid, _seq, log_time = struct.unpack_from("<HIQ", buf, body)
                if cid not in walk.channels:
                    walk.problems.append(f"{where}: message on unknown channel {cid} skipped")
                else:
                    msgs.setdefault(cid, []).append((log_time, pos))
                    nbytes[cid] = nbytes.get(cid, 0) + length - 22
                    if on_message is not None:
                        on_message(cid, log_time, bytes(buf[body + 22 : end]))
            elif op == 0x03:
                _parse_schema(buf[:end], body, walk)
            elif op == 0x04:
                _parse_channel(buf[:end], body, walk)
        except (struct.error, UnicodeDecodeError) as exc:
            raise _Damaged(
                f"{where}: unreadable record (op 0x{op:02x}) at byte {pos}: {_describe(exc)}"
            ) from None
        pos = end
    return msgs, nbytes


def _parse_chunk(
    body: bytes, pos: int, walk: _McapWalk, on_message: OnMessage, where: str
) -> _Chunk:
    from rosbags.rosbag2.storage_mcap import decompress

    try:
        t0, t1, usize, crc = struct.unpack_from("<QQQI", body, 0)
        comp, p = _read_str(body, 28)
        (csize,) = struct.unpack_from("<Q", body, p)
    except (struct.error, UnicodeDecodeError) as exc:
        raise _Damaged(f"{where}: chunk at byte {pos}: unreadable header ({exc})") from None
    data = body[p + 8 : p + 8 + csize]
    if len(data) != csize:
        raise _Damaged(f"{where}: chunk at byte {pos}: {len(data)} of {csize} data bytes")
    try:
        payload = decompress(data, comp, usize, crc)
    except Exception as exc:  # noqa: BLE001 - rosbags / lz4 / zstd errors
        raise _Damaged(f"{where}: chunk at byte {pos}: {_describe(exc)}") from None
    msgs, nbytes = _walk_records(payload, walk, on_message, f"{where} chunk at byte {pos}")
    end = pos + 9 + len(body)
    return _Chunk(pos, 9 + len(body), t0, t1, usize, csize, comp, msgs, nbytes, {}, end)


def complete_prefix(buf) -> int:
    """Length of the longest prefix of ``buf`` made of complete records (opcode, length,
    body): where a cut chunk's records stop being whole."""
    pos, n = 0, len(buf)
    while pos + 9 <= n:
        (length,) = struct.unpack_from("<Q", buf, pos + 1)
        if length > n - pos - 9:
            break
        pos += 9 + length
    return pos


def _salvage_partial_chunk(
    body: bytes, pos: int, walk: _McapWalk, on_message: OnMessage, where: str
) -> None:
    """The complete records of a Chunk record cut by the end of the file (a writer killed
    while the chunk was being written, or a file cut inside it): an uncompressed chunk's
    records are read as far as they are whole (Schema, Channel and Message records; the
    chunk's CRC covers the whole chunk, so none is checked) and kept in ``walk.partial``
    for the repair; ``on_message`` gets their messages. A compressed chunk cannot be read
    in part: noted, nothing salvaged."""
    try:
        _t0, _t1, _usize, _crc = struct.unpack_from("<QQQI", body, 0)
        comp, p = _read_str(body, 28)
        struct.unpack_from("<Q", body, p)
    except (struct.error, UnicodeDecodeError):
        walk.problems.append(f"{where}: cut chunk at byte {pos}: header incomplete, nothing kept")
        return
    if comp:
        walk.problems.append(
            f"{where}: cut chunk at byte {pos} is {comp}-compressed: its records cannot be "
            "read in part"
        )
        return
    data = body[p + 8 :]
    keep = complete_prefix(data)
    try:
        msgs, nbytes = _walk_records(data[:keep], walk, on_message, f"{where} cut chunk")
    except _Damaged as exc:
        walk.problems.append(str(exc))
        return
    n = sum(len(v) for v in msgs.values())
    walk.partial = (pos, bytes(data[:keep]), msgs, nbytes)
    walk.problems.append(
        f"{where}: cut chunk at byte {pos}: {n} complete message(s) in its first {keep} bytes "
        "salvaged"
    )


def _walk_mcap(path: Path, on_message: OnMessage = None, limit: int | None = None) -> _McapWalk:
    """Walk the data section of an mcap file record by record, never past ``limit`` bytes;
    stops at the end of the data section, at the first incomplete or unreadable record."""
    walk = _McapWalk()
    where = str(path)
    with open_file(path, path.parent) as fh:
        size = walk.size = os.fstat(fh.fileno()).st_size
        if limit is not None:
            size = min(size, limit)
        head = fh.read(17)
        if len(head) < 8 or head[:8] != MCAP_MAGIC:
            walk.problems.append(
                f"{where}: not an mcap file (bad magic)"
                if len(head) >= 8
                else f"{where}: {len(head)}-byte file, no mcap header"
            )
            return walk
        if len(head) < 17 or head[8] != 0x01:
            walk.problems.append(f"{where}: no mcap header record")
            return walk
        (hlen,) = struct.unpack_from("<Q", head, 9)
        if 17 + hlen > size:
            walk.problems.append(f"{where}: truncated mcap header record")
            return walk
        walk.header_ok = True
        pos = walk.data_start = walk.data_end = 17 + hlen
        last = None
        while True:
            if pos >= size:
                walk.problems.append(
                    f"{where}: ends at byte {pos} without data end or footer "
                    "(recording not closed)"
                )
                break
            if pos + 9 > size:
                walk.problems.append(f"{where}: truncated record header at byte {pos}")
                break
            fh.seek(pos)
            rh = fh.read(9)
            op = rh[0]
            (length,) = struct.unpack_from("<Q", rh, 1)
            end = pos + 9 + length
            if op in _END_OPS:
                walk.ended = True
                break
            if end > size:
                walk.problems.append(
                    f"{where}: truncated record (op 0x{op:02x}) at byte {pos}: "
                    f"{size - pos - 9} of {length} bytes present"
                )
                if op == 0x06:
                    _salvage_partial_chunk(fh.read(size - pos - 9), pos, walk, on_message, where)
                break
            if op not in _DATA_OPS and op < 0x80:
                walk.problems.append(f"{where}: invalid record (op 0x{op:02x}) at byte {pos}")
                break
            try:
                if op == 0x06:
                    last = _parse_chunk(fh.read(length), pos, walk, on_message, where)
                    walk.chunks.append(last)
                elif op == 0x07:
                    body = fh.read(length)
                    if last is not None and last.index_end == pos and len(body) >= 6:
                        (cid,) = struct.unpack_from("<H", body, 0)
                        last.index[cid] = pos
                        last.index_end = end
                    else:
                        walk.problems.append(
                            f"{where}: message index at byte {pos} does not "
                            "follow a chunk; ignored"
                        )
                elif op in (0x03, 0x04, 0x05):
                    body = fh.read(length)
                    rec = _record(op, body)
                    if op == 0x05:
                        walk.unchunked += 1
                    _walk_records(rec, walk, on_message, where)
                elif op == 0x0C:
                    walk.metadata_records += 1
            except _Damaged as exc:
                walk.problems.append(str(exc))
                break
            pos = walk.data_end = end
    return walk


def _salvage_mcap(path: Path, topics: set | None, src: _Source, problems: list) -> None:
    """Complete records of an mcap file rosbags cannot open (no footer: killed writer)."""
    records: list[tuple[int, int, bytes]] = []

    def keep(cid: int, log_time: int, data: bytes) -> None:
        records.append((cid, log_time, data))

    walk = _walk_mcap(path, on_message=keep)
    problems.extend(walk.problems)
    for cid, (sid, topic, _enc, _meta) in walk.channels.items():
        if sid in walk.schemas:
            name, enc, text = walk.schemas[sid]
            src.types[topic] = name
            if enc == "ros2msg":
                src.msgdefs.setdefault(name, text)
    for cid, log_time, data in records:
        topic = walk.channels[cid][1]
        if topic in src.types and (topics is None or topic in topics):
            src.records.append((topic, log_time, data))
