"""Writing rosbag2 recordings: :class:`BagWriter`.

:class:`BagWriter` is a context manager around ``rosbags.rosbag2.Writer`` (format
version 9); :meth:`BagWriter.write_many` writes finished records in bulk (e.g. the blocks
of :func:`~lpv_sysid.io.bag.cdr.layout.encode_block`). Messages are CDR-serialised with the
ROS 2 Jazzy typestore and each topic is registered with its full message definition and
RIHS01 type hash, so ``ros2 bag info`` / ``ros2 bag play`` accept the result, and with the
offered QoS profile (default: reliable, volatile, keep-last 10 -- rclpy's default
publisher profile).

Durability (what a ``kill -9``, a crash or a full disk can cost): rosbags alone keeps an
mcap chunk of up to 1 MiB in memory and commits sqlite3 once, at close, so a killed
recorder loses the pending chunk (mcap) or everything (sqlite3). :class:`BagWriter`
therefore *flushes* -- closes the pending mcap chunk and hands it to the OS, or commits the
sqlite3 transaction -- as soon as the oldest unflushed message is ``flush_interval_s`` old
(default 0.5 s, checked at every write and by :meth:`BagWriter.flush_if_due`) or
``flush_messages`` are pending (default 1000), and before an mcap chunk would exceed
``chunk_bytes``. A killed process thus loses at most the last ``flush_interval_s`` of data;
``fsync=True`` also survives a power cut (sqlite3 runs with ``synchronous=OFF`` unless
``fsync``: safe against a process kill, not against a power cut).
:attr:`BagWriter.durable_counts` are the messages per topic known to be on disk. While
open, the directory holds the writer's lock and disk reserve
(:mod:`lpv_sysid.io.bag.durability`); on a write error the reserve is released and what
was written is saved and indexed (:mod:`lpv_sysid.io.bag.writer_recovery`) before a
:class:`~lpv_sysid.errors.BagError` naming the path and what is readable is raised. A clean
close removes the lock file.

Relies on the storage attributes of rosbags 0.11.9 (``McapWriter.chunk``, ``chunks``,
``close_chunk``, ``bio``; ``Sqlite3Writer.conn``), hence ``Any`` for the storage objects.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import shutil
import sqlite3
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Literal, Mapping, NoReturn

from lpv_sysid.errors import BagError
from lpv_sysid.io.bag.durability import LOCK_FILE, RESERVE_BYTES, DiskReserve, _describe
from lpv_sysid.io.bag.mcap import append_message, write_chunk_crcs
from lpv_sysid.io.bag.mcap.records import _MSG_RECORD_OVERHEAD
from lpv_sysid.io.bag.repair import RepairReport
from lpv_sysid.io.bag.typestore import jazzy_typestore, make_qos
from lpv_sysid.io.bag.writer_recovery import recover

LOG = logging.getLogger(__name__)

STORAGES = ("mcap", "sqlite3")
FLUSH_INTERVAL_S = 0.5
FLUSH_MESSAGES = 1000
#: rosbags 0.11.9 ``McapWriter.write`` closes a chunk by itself above 2**20 bytes; the
#: writer flushes before that so chunk boundaries (= what is durable) stay its own
MAX_CHUNK_BYTES = 1 << 20


class BagWriter:
    """rosbag2 writer: ``with BagWriter(path) as bag: bag.add_topic(...); bag.write(...)``.

    ``path`` is the bag directory to create (it must not exist). ``storage`` is ``"mcap"``
    (default) or ``"sqlite3"``. Durability options (module docstring): ``flush_interval_s``
    (> 0, default 0.5) and ``flush_messages`` (>= 1, default 1000) bound what a killed
    process can lose, ``chunk_bytes`` (at most 1 MiB) bounds an mcap chunk, ``fsync``
    makes every flush survive a power cut, ``reserve_bytes`` (default 1 MiB) is kept free
    for closing on a full disk. ``clock`` (seconds, monotonic) times the flushes.
    """

    def __init__(
        self,
        path,
        storage: str = "mcap",
        *,
        typestore=None,
        chunk_bytes: int = MAX_CHUNK_BYTES,
        flush_interval_s: float = FLUSH_INTERVAL_S,
        flush_messages: int = FLUSH_MESSAGES,
        fsync: bool = False,
        reserve_bytes: int = RESERVE_BYTES,
        clock: Callable[[], float] = time.monotonic,
    ):
        if storage not in STORAGES:
            raise BagError(f"bag {path}: storage must be one of {STORAGES}, got {storage!r}")
        if isinstance(chunk_bytes, bool) or not isinstance(chunk_bytes, int) or chunk_bytes <= 0:
            raise BagError(
                f"bag {path}: chunk_bytes must be a positive integer, got {chunk_bytes!r}"
            )
        if (
            isinstance(flush_interval_s, bool)
            or not isinstance(flush_interval_s, (int, float))
            or not math.isfinite(flush_interval_s)
            or flush_interval_s <= 0
        ):
            raise BagError(
                f"bag {path}: flush_interval_s must be a finite number > 0, "
                f"got {flush_interval_s!r}"
            )
        for name, value, lo in (
            ("flush_messages", flush_messages, 1),
            ("reserve_bytes", reserve_bytes, 0),
        ):
            if isinstance(value, bool) or not isinstance(value, int) or value < lo:
                raise BagError(f"bag {path}: {name} must be an integer >= {lo}, got {value!r}")
        self.path = Path(path)
        self.storage = storage
        self.chunk_bytes = min(int(chunk_bytes), MAX_CHUNK_BYTES)
        self.flush_interval_s = float(flush_interval_s)
        self.flush_messages = int(flush_messages)
        self.fsync = bool(fsync)
        self.reserve_bytes = int(reserve_bytes)
        self.typestore = typestore if typestore is not None else jazzy_typestore()
        self.counts: dict[str, int] = {}
        #: messages per topic known to be on disk (last flush; the file's content after a
        #: failed close)
        self.durable_counts: dict[str, int] = {}
        #: number of successful flushes (a change means ``durable_counts`` moved)
        self.flushes = 0
        #: the :class:`RepairReport` of the recovery after a write error, if there was one
        self.repair: RepairReport | None = None
        self.types: dict[str, str] = {}
        self._clock = clock
        self._writer: Any = None  # rosbags.rosbag2.Writer (its storage internals are used)
        self._connections: dict[str, Any] = {}
        self._closed = False
        self._failed: str | None = None
        self._reserve: DiskReserve | None = None
        self._header_end = 0
        self._pending_rows: list = []  # sqlite3: rows of the open transaction
        self._pending_n = 0
        self._oldest = 0.0

    @property
    def _mcap(self) -> bool:
        return self.storage == "mcap"

    # -- lifecycle ---------------------------------------------------------------
    def open(self) -> "BagWriter":
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

        if self._writer is not None or self._closed:
            raise BagError(f"bag {self.path}: already opened")
        plugin = StoragePlugin.MCAP if self._mcap else StoragePlugin.SQLITE3
        existed = self.path.exists()
        writer = None
        try:
            writer = Writer(self.path, version=9, storage_plugin=plugin)
            writer.open()
            storage: Any = writer.storage
            if self._mcap:
                write_chunk_crcs(storage)  # flipped bytes in a chunk are caught on read
                storage.bio.flush()  # the header is on disk from the start
                self._header_end = storage.bio.tell()
            else:
                storage.conn.execute(f"PRAGMA synchronous={'FULL' if self.fsync else 'OFF'}")
            self._reserve = DiskReserve(self.path / LOCK_FILE, self.reserve_bytes).acquire()
        except (WriterError, OSError, sqlite3.Error) as exc:
            if writer is not None and writer.storage is not None:
                with contextlib.suppress(Exception):
                    writer.abort()
            if not existed:
                shutil.rmtree(self.path, ignore_errors=True)
            why = exc if isinstance(exc, WriterError) else _describe(exc)
            raise BagError(f"bag {self.path}: cannot create: {why}") from None
        self._writer = writer
        return self

    def __enter__(self) -> "BagWriter":
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> Literal[False]:
        # Always finalise (also on an exception in the with block) so the bag stays readable.
        if self._writer is not None:
            if exc_type is None:
                self.close()
            else:
                try:
                    self.close()
                except BagError as close_exc:
                    LOG.error("%s", close_exc)
        return False

    @property
    def is_open(self) -> bool:
        return self._writer is not None

    @property
    def pending_messages(self) -> int:
        """Messages written since the last flush (what a kill would cost now)."""
        return self._pending_n

    def close(self) -> None:
        """Write index, footer and ``metadata.yaml``; idempotent. A failing close goes
        through the recovery of a write error and raises :class:`BagError`."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        self._closed = True
        try:
            writer.close()
        except Exception as exc:  # noqa: BLE001 - every failure must become a BagError
            state = recover(self, writer)
            raise BagError(
                f"bag {self.path}: closing failed ({_describe(exc)}); {state}"
            ) from None
        self.durable_counts = dict(self.counts)
        self._pending_n = 0
        self._pending_rows.clear()
        if self._reserve is not None:
            self._reserve.release()
        LOG.info("closed bag %s (%d messages)", self.path, sum(self.counts.values()))

    # -- topics and messages -----------------------------------------------------------
    def add_topic(self, topic: str, msgtype: str, qos: Mapping | None = None) -> None:
        """Register ``topic`` with type ``pkg/msg/Name`` and its offered QoS profile."""
        self._check_open()
        if not isinstance(topic, str) or not topic:
            raise BagError(
                f"bag {self.path}: topic name must be a non-empty string, got {topic!r}"
            )
        if topic in self._connections:
            if self.types[topic] != msgtype:
                raise BagError(
                    f"bag {self.path}: topic {topic!r} already registered as "
                    f"{self.types[topic]}, not {msgtype}"
                )
            return
        if msgtype not in self.typestore.types:
            raise BagError(f"bag {self.path}: topic {topic!r}: unknown message type {msgtype!r}")
        profile = make_qos(qos)
        try:
            conn = self._writer.add_connection(
                topic, msgtype, typestore=self.typestore, offered_qos_profiles=[profile]
            )
        except Exception as exc:  # noqa: BLE001
            self._fail(f"registering topic {topic!r} failed", exc)
        self._connections[topic] = conn
        self.types[topic] = msgtype
        self.counts[topic] = 0
        self.durable_counts[topic] = 0

    def write(self, topic: str, stamp_ns: int, msg) -> None:
        """CDR-serialise ``msg`` (a rosbags message of the topic's type) and write it at
        ``stamp_ns`` (int nanoseconds, >= 0). Out-of-order stamps are accepted."""
        msgtype = self._topic_type(topic)
        have = getattr(msg, "__msgtype__", None)
        if have is not None and have != msgtype:
            raise BagError(f"bag {self.path}: topic {topic!r} has type {msgtype}, got a {have}")
        try:
            data = self.typestore.serialize_cdr(msg, msgtype)
        except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds
            raise BagError(
                f"bag {self.path}: topic {topic!r}: cannot serialise message as "
                f"{msgtype}: {_describe(exc)}"
            ) from None
        self._write(topic, stamp_ns, data)

    def write_raw(self, topic: str, stamp_ns: int, data: bytes) -> None:
        """Write an already CDR-serialised message (e.g. from a ``raw=True`` subscription)."""
        self._topic_type(topic)
        self._write(topic, stamp_ns, bytes(data))

    def write_many(self, rows: Iterable) -> int:
        """Write already CDR-serialised messages ``(topic, stamp_ns, data)`` in the given
        order: the same records, chunks, flushes and counts as the same sequence of
        :meth:`write_raw` calls, without rosbags' per-message overhead (mcap: the records
        go straight into the pending chunk, as ``McapWriter.write`` of rosbags 0.11.9 writes
        them). ``data`` is bytes or a row of the uint8 block of :func:`encode_block`.
        Returns the number of messages written."""
        self._check_open()
        if (
            not self._mcap
            or getattr(self._writer, "compression_mode", None) is None
            or self._writer.compression_mode.name != "NONE"
        ):
            n = 0
            for topic, stamp_ns, data in rows:
                self.write_raw(topic, stamp_ns, data)
                n += 1
            return n
        writer = self._writer
        conns: dict[str, int] = {}
        n = 0
        topic = None
        try:
            for topic, stamp_ns, data in rows:
                cid = conns.get(topic)
                if cid is None:
                    self._topic_type(topic)
                    cid = conns[topic] = self._connections[topic].id
                ns = self._stamp(topic, stamp_ns)
                self._make_room(len(data))
                closed = append_message(writer, cid, ns, data)
                self.counts[topic] += 1
                n += 1
                self._count_pending(closed)
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001
            self._fail(f"writing {topic!r} failed", exc)
        return n

    def flush(self, fsync: bool | None = None) -> None:
        """Make everything written so far durable now: close the pending mcap chunk and
        hand it to the OS / commit sqlite3 (``fsync``: also to the device; default: the
        writer's ``fsync`` option).

        Relies on the storage attributes of rosbags 0.11.9 (``McapWriter.chunk``,
        ``chunks``, ``close_chunk``, ``bio``; ``Sqlite3Writer.conn``).
        """
        self._check_open()
        try:
            self._flush(fsync)
        except Exception as exc:  # noqa: BLE001
            self._fail("flush failed", exc)

    def flush_if_due(self) -> bool:
        """Flush when the oldest unflushed message is ``flush_interval_s`` old (for a timer:
        writes check this themselves, a timer covers a stream that stops). True if it did."""
        if self._writer is None or not self._pending_n:
            return False
        if self._clock() - self._oldest < self.flush_interval_s:
            return False
        self.flush()
        return True

    # -- internals ------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._writer is None:
            why = f" (after error: {self._failed})" if self._failed else ""
            raise BagError(f"bag {self.path}: not open{why}")

    def _topic_type(self, topic: str) -> str:
        self._check_open()
        try:
            return self.types[topic]
        except KeyError:
            raise BagError(
                f"bag {self.path}: topic {topic!r} was not added "
                f"(add_topic first); known: {sorted(self.types)}"
            ) from None

    def _stamp(self, topic: str, stamp_ns: int | float) -> int:
        """``stamp_ns`` as int nanoseconds in [0, 2^63) (BagError otherwise)."""
        if isinstance(stamp_ns, float) and not math.isfinite(stamp_ns):
            raise BagError(f"bag {self.path}: topic {topic!r}: stamp {stamp_ns!r} is not finite")
        ns = int(stamp_ns)
        if not 0 <= ns < 2**63:
            raise BagError(f"bag {self.path}: topic {topic!r}: stamp {ns} ns outside [0, 2^63)")
        return ns

    def _make_room(self, size: int) -> None:
        """mcap: flush first when a record of ``size`` bytes would take the pending chunk
        past ``chunk_bytes`` (chunk boundaries are what is durable)."""
        chunk = self._writer.storage.chunk
        if chunk.msgs and chunk.bio.tell() + _MSG_RECORD_OVERHEAD + size > self.chunk_bytes:
            self._flush()

    def _count_pending(self, chunk_closed: bool) -> None:
        """One more message since the last flush; flush when rosbags closed a chunk by
        itself, ``flush_messages`` are pending or the oldest is ``flush_interval_s`` old."""
        now = self._clock()
        if not self._pending_n:
            self._oldest = now
        self._pending_n += 1
        if (
            chunk_closed
            or self._pending_n >= self.flush_messages
            or now - self._oldest >= self.flush_interval_s
        ):
            self._flush()

    def _write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        ns = self._stamp(topic, stamp_ns)
        conn = self._connections[topic]
        storage = self._writer.storage
        try:
            if self._mcap:
                self._make_room(len(data))
            nchunks = len(storage.chunks) if self._mcap else 0
            self._writer.write(conn, ns, data)
            self.counts[topic] += 1
            if not self._mcap:
                self._pending_rows.append((conn.id, ns, data))
            self._count_pending(self._mcap and len(storage.chunks) != nchunks)
        except Exception as exc:  # noqa: BLE001
            self._fail(f"writing {topic!r} failed", exc)

    def _flush(self, fsync: bool | None = None) -> None:
        sync = self.fsync if fsync is None else bool(fsync)
        storage = self._writer.storage
        if self._mcap:
            if storage.chunk.msgs:
                storage.close_chunk()
            storage.bio.flush()
            if sync:
                os.fsync(storage.bio.fileno())
        else:
            storage.conn.commit()
            if sync and not self.fsync:  # synchronous=OFF: sync the file ourselves
                fd = os.open(storage.path, os.O_RDONLY)
                try:
                    os.fsync(fd)
                finally:
                    os.close(fd)
        self.durable_counts = dict(self.counts)
        self._pending_rows.clear()
        self._pending_n = 0
        self.flushes += 1

    def _fail(self, what: str, exc: BaseException) -> NoReturn:
        """Recover what was written (so it stays readable) and raise a BagError naming the
        path, the error and what is readable."""
        self._failed = f"{what}: {_describe(exc)}"
        writer, self._writer = self._writer, None
        self._closed = True
        state = recover(self, writer) if writer is not None else "bag was not open"
        raise BagError(f"bag {self.path}: {what} ({_describe(exc)}); {state}") from None
