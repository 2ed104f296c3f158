"""MCAP record primitives shared by the index reader, the salvage walk and the repair.

MCAP records are (opcode u8, length u64, body); strings and byte arrays in a body are
(length u32, bytes). See https://mcap.dev/spec.
"""

from __future__ import annotations

import struct
import zlib
from typing import Any

MCAP_MAGIC = b"\x89MCAP0\r\n"
_MCAP_OPLEN = struct.Struct("<BQ")
_MCAP_MSG = struct.Struct("<HIQ")  # channel id, sequence, log time
_MCAP_MSG_RECORD = struct.Struct("<BQHIQQ")  # opcode, length, channel, sequence, log, publish
_MSG_RECORD_OVERHEAD = 9 + 22  # mcap Message record: opcode + length + header
_MCAP_CHUNK_HEAD = struct.Struct("<QQQI")  # start, end, uncompressed size, crc
_MCAP_FOOTER_HEAD = b"\x02\x14\x00\x00\x00\x00\x00\x00\x00"


def _read_str(buf, pos: int) -> tuple[str, int]:
    data, end = _read_bytes(buf, pos)
    return data.decode("utf-8"), end


def _read_bytes(buf, pos: int) -> tuple[bytes, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end = pos + 4 + n
    if end > len(buf):
        raise struct.error("string beyond record")
    return bytes(buf[pos + 4 : end]), end


def _enc_str(text: str) -> bytes:
    data = text.encode("utf-8")
    return struct.pack("<I", len(data)) + data


def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def chunk_crc(data: bytes) -> int:
    """The ``uncompressed_crc`` of a Chunk record: CRC-32 (zlib, as the MCAP spec and
    rosbags' ``decompress`` check it) of the uncompressed records."""
    return zlib.crc32(data) & 0xFFFFFFFF


def write_chunk_crcs(storage: Any) -> None:
    """Make a rosbags 0.11.9 ``McapWriter`` write the CRC of every chunk it closes (it
    writes 0, "no CRC", so a flipped byte inside a chunk was read silently): its
    ``close_chunk`` is wrapped to patch the ``uncompressed_crc`` field (offset 9 + 24 in the
    Chunk record) after the record is written. Every chunk goes through ``close_chunk``
    (rosbags' own size limit, :func:`append_message`, the writer's flush and close)."""
    original = storage.close_chunk

    def close_chunk() -> None:
        data = storage.chunk.bio.getvalue()
        start = storage.bio.tell()
        original()
        end = storage.bio.tell()
        storage.bio.seek(start + 9 + 24)
        storage.bio.write(struct.pack("<I", chunk_crc(data)))
        storage.bio.seek(end)

    storage.close_chunk = close_chunk


def append_message(writer: Any, cid: int, ns: int, data: Any) -> bool:
    """Append one Message record to the chunk a rosbags 0.11.9 ``Writer`` (mcap storage)
    holds in memory, exactly as its ``Writer.write`` + ``McapWriter.write`` do it, without
    their per-call overhead (``BagWriter.write_many``; test_bag_codec.py compares the files
    byte for byte). Returns True when the chunk went over 1 MiB and was closed, as rosbags
    closes it."""
    storage = writer.storage
    chunk = storage.chunk
    if ns < storage.message_start_time:
        storage.message_start_time = ns
    if ns > storage.message_end_time:
        storage.message_end_time = ns
    storage.channel_stats[cid] += 1
    if ns < chunk.message_start_time:
        chunk.message_start_time = ns
    if ns > chunk.message_end_time:
        chunk.message_end_time = ns
    bio = chunk.bio
    chunk.msgs[cid].append((ns, bio.tell()))
    bio.write(_MCAP_MSG_RECORD.pack(0x05, 22 + len(data), cid, 0, ns, ns))
    bio.write(data)
    closed = bio.tell() > 2**20
    if closed:
        storage.close_chunk()
    writer.counts[cid] += 1  # Writer.write
    if ns < writer.min_timestamp:
        writer.min_timestamp = ns
    if ns > writer.max_timestamp:
        writer.max_timestamp = ns
    return closed
