"""Saving what a failed :class:`~lpv_sysid.io.bag.writer.BagWriter` held.

After a write or close error (disk full, ...) the writer gives its disk reserve back, saves
the messages still in memory (the pending mcap chunk, the uncommitted sqlite3 rows),
indexes the file and writes ``metadata.yaml`` from what it holds
(:func:`~lpv_sysid.io.bag.repair.repair_bag`).
"""

from __future__ import annotations

import contextlib
import logging
import sqlite3
import struct
from pathlib import Path
from typing import Any, Optional, Protocol

from lpv_sysid.io.bag.durability import DiskReserve
from lpv_sysid.io.bag.repair import RepairReport, repair_bag


class FailedWriter(Protocol):
    """What :func:`recover` reads and sets of the failed
    :class:`~lpv_sysid.io.bag.writer.BagWriter`."""

    path: Path
    counts: dict[str, int]
    durable_counts: dict[str, int]
    repair: Optional[RepairReport]
    _reserve: Optional[DiskReserve]
    _header_end: int
    _pending_rows: list

    @property
    def _mcap(self) -> bool: ...


LOG = logging.getLogger(__name__)


def recover(bw: FailedWriter, writer: Any) -> str:
    """After a write/close error of ``bw`` (whose rosbags ``writer`` failed): give the
    disk reserve back, save the messages still in memory (the pending mcap chunk, the
    uncommitted sqlite3 rows), index the file and write ``metadata.yaml`` from what it
    holds (:func:`repair_bag`); set ``bw.repair`` and ``bw.durable_counts`` to that.
    Returns a sentence for the error message."""
    if bw._reserve is not None:
        bw._reserve.release()
    with contextlib.suppress(OSError):
        (bw.path / "metadata.yaml.tmp").unlink()
    storage = writer.storage
    try:
        if bw._mcap:
            limit: int | None = None
            pending: tuple[bytes, int, int] | None = None
            if storage is not None:
                pending = _pending_chunk(storage)
                limit = _completed_end(storage, bw._header_end)
                with contextlib.suppress(Exception):
                    storage.bio.close()  # hands over what it can; the walk checks
            rep = repair_bag(bw.path, _limit=limit, _pending=pending)
        else:
            if storage is not None:
                settle_sqlite(bw, storage)
            rep = repair_bag(bw.path)
    except Exception as exc:  # noqa: BLE001 - the write error is what gets raised
        return (
            f"what reached the disk stays there, but it could not be indexed ({exc}); "
            f"run `lpv-sysid bag repair {bw.path}` once there is space"
        )
    bw.repair = rep
    bw.durable_counts = {t: rep.topics[t].count if t in rep.topics else 0 for t in bw.counts}
    lost = sum(bw.counts.values()) - rep.messages
    if lost <= 0:
        return f"closed; all {rep.messages} message(s) written are readable"
    return (
        f"closed; {rep.messages} message(s) readable, the last {lost} written could not be saved"
    )


def settle_sqlite(bw: FailedWriter, storage: Any) -> None:
    """Commit what the failed transaction still holds; if SQLite rolled it back, write
    the pending rows again (the reserve just freed makes room for them)."""
    conn = storage.conn
    try:
        try:
            conn.commit()
        except sqlite3.Error:
            with contextlib.suppress(sqlite3.Error):
                conn.rollback()
        (have,) = conn.execute("SELECT count(*) FROM messages").fetchone()
        if bw._pending_rows and have == sum(bw.durable_counts.values()):
            conn.executemany(
                "INSERT INTO messages (topic_id, timestamp, data) VALUES(?, ?, ?)",
                bw._pending_rows,
            )
            conn.commit()
    except sqlite3.Error as exc:
        LOG.error("bag %s: saving the uncommitted rows failed: %s", bw.path, exc)
        with contextlib.suppress(sqlite3.Error):
            conn.rollback()
    finally:
        with contextlib.suppress(sqlite3.Error):
            conn.close()


def _pending_chunk(storage: Any) -> tuple[bytes, int, int] | None:
    """``(records, start_ns, end_ns)`` of the mcap chunk rosbags holds in memory, or None."""
    chunk = storage.chunk
    data = chunk.bio.getvalue()
    if not data:
        return None
    if not chunk.msgs:
        return data, 0, 0
    return data, chunk.message_start_time, chunk.message_end_time


def _completed_end(storage: Any, header_end: int) -> int:
    """File offset after the last chunk (and its message indexes) rosbags finished writing
    to its buffer; beyond it the file holds at most a partial write of the pending chunk."""
    if not storage.chunks:
        return header_end
    rec = storage.chunks[-1].getvalue()  # a ChunkIndex record body
    _t0, _t1, start, length = struct.unpack_from("<QQQQ", rec, 0)
    (map_len,) = struct.unpack_from("<I", rec, 32)
    (index_len,) = struct.unpack_from("<Q", rec, 36 + map_len)
    return start + length + index_len
