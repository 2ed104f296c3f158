"""rosbag2 recordings (mcap by default, sqlite3 optional) through rosbags 0.11.9.

This module is the only owner of the bag format: writing, reading, salvaging and repairing.

Writing
    :class:`BagWriter` is a context manager around ``rosbags.rosbag2.Writer`` (format
    version 9); :meth:`BagWriter.write_many` writes finished records in bulk (e.g. the
    blocks of :func:`encode_block`, which fills copies of one serialised template message
    with columns of values). Messages are CDR-serialised with the ROS 2 Jazzy typestore and each topic
    is registered with its full message definition and RIHS01 type hash, so ``ros2 bag
    info`` / ``ros2 bag play`` accept the result, and with the offered QoS profile
    (default: reliable, volatile, keep-last 10 -- rclpy's default publisher profile).

Durability (what a ``kill -9``, a crash or a full disk can cost)
    rosbags alone keeps an mcap chunk of up to 1 MiB in memory and commits sqlite3 once,
    at close, so a killed recorder loses the pending chunk (mcap) or everything (sqlite3).
    :class:`BagWriter` therefore *flushes* -- closes the pending mcap chunk and hands it
    to the OS, or commits the sqlite3 transaction -- as soon as the oldest unflushed
    message is ``flush_interval_s`` old (default 0.5 s, checked at every write and by
    :meth:`BagWriter.flush_if_due`) or ``flush_messages`` are pending (default 1000), and
    before an mcap chunk would exceed ``chunk_bytes``. A killed process thus loses at most
    the last ``flush_interval_s`` of data; ``fsync=True`` also survives a power cut
    (sqlite3 runs with ``synchronous=OFF`` unless ``fsync``: safe against a process kill,
    not against a power cut). :attr:`BagWriter.durable_counts` are the messages per topic
    known to be on disk.

    While open, the bag directory holds ``.lpv_sysid_writing``: a file locked with
    ``flock`` (the kernel drops the lock when the process dies, also on ``kill -9``, so a
    held lock means "a live writer", see :func:`writer_alive`) and filled with
    ``reserve_bytes`` (default 1 MiB) of disk space. On a write error the reserve is
    released first, so that even on a full disk the pending messages, the mcap index and
    ``metadata.yaml`` can still be written (:meth:`BagWriter._recover`); a
    :class:`BagError` naming the path and what is readable is raised after that. A clean
    close removes the file.

Repair
    :func:`repair_bag` (``lpv-sysid bag repair DIR``, in the spirit of ``ros2 bag
    reindex``) makes a killed or starved recording readable by standard tools: for mcap
    it cuts the incomplete tail (a record the process did not finish), regenerates the
    message index of the last chunk if it was cut, appends a summary section (schemas,
    channels, chunk indexes, statistics) and footer in place -- nothing before the cut is
    rewritten, so it needs only a few kB even on a full disk -- and checks the result with
    rosbags' own reader; for sqlite3 it lets SQLite roll back an uncommitted transaction
    (hot journal). Then it writes ``metadata.yaml`` from what the storage file really
    holds. A bag locked by a live writer is refused.

Reading
    :func:`read_bag` returns ``{topic: [(stamp_ns, msg), ...]}``, :func:`read_arrays` the
    same records column-wise (``{topic: TopicArrays}``: one numpy array per numeric field,
    e.g. ``fields["pose.pose.position.x"]``), :func:`topic_info` counts and time spans.
    Messages come back sorted by the bag timestamp (equal stamps in file order): rosbag2
    allows out-of-order writes and stores them as written, but readers (``AnyReader`` and
    ``ros2 bag play``) deliver them in time order. Messages whose definitions equal the
    Jazzy ones are returned as instances of the Jazzy typestore classes (the same classes
    :meth:`lpv_sysid.io.messages.MsgFactory.rosbags` builds), with the values rosbags'
    ``deserialize_cdr`` gives.

    Fast paths (values identical to rosbags', checked in test_bag_codec.py): a healthy
    indexed mcap bag is opened from its summary section and ``metadata.yaml`` directly
    (rosbags' reader parses them with a pure-Python YAML library), its chunks are
    decompressed by rosbags' ``decompress`` (size and CRC checked) and the records of each
    topic are gathered through the message indexes with array indexing; the fixed-layout
    records the package writes are then decoded a topic at a time by the CDR block codec
    (:class:`CdrLayout`, probed against rosbags before use) and ``read_bag`` builds the
    message objects from the decoded columns; ``topic_info`` reads only the summary and
    the message indexes. Whatever these paths do not recognise -- sqlite3, compression,
    IDL definitions, a metadata.yaml that disagrees with the file, a record or index that
    is not as rosbags would read it -- goes through ``AnyReader`` and ``deserialize_cdr``
    as before (which also names the problem of a damaged bag).

    A missing ``metadata.yaml`` or a truncated/corrupt storage file raises
    :class:`BagError`; with ``strict=False`` whatever can be read is returned instead and
    the problems are listed in ``result.problems``: the storage file is read directly
    (rosbags reads ``.mcap`` / ``.db3`` files without metadata), and if that fails too, the
    complete records of a truncated mcap are recovered by a record-level walk and the
    readable rows of a damaged sqlite3 file are read with the sqlite3 module. The walk is
    written here because rosbags' ``McapReader`` refuses any file without a valid footer
    (it seeks the footer first) and the reference ``mcap`` library is not a dependency;
    the same walk drives :func:`repair_bag`, after which rosbags reads the file itself.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import fcntl
import functools
import logging
import math
import os
import shutil
import sqlite3
import struct
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Mapping

import numpy as np
import yaml

from lpv_sysid.errors import BagError

LOG = logging.getLogger(__name__)

__all__ = [
    "BagWriter",
    "BagContents",
    "BagArrays",
    "TopicArrays",
    "TopicStats",
    "RepairReport",
    "read_bag",
    "read_arrays",
    "topic_info",
    "encode_block",
    "records_close",
    "CdrLayout",
    "LayoutError",
    "repair_bag",
    "writer_alive",
    "atomic_write_text",
    "DiskReserve",
    "jazzy_typestore",
    "DEFAULT_QOS",
    "make_qos",
    "LOCK_FILE",
]

STORAGES = ("mcap", "sqlite3")
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: lock + disk reserve of an open :class:`BagWriter`, inside the bag directory
LOCK_FILE = ".lpv_sysid_writing"
FLUSH_INTERVAL_S = 0.5
FLUSH_MESSAGES = 1000
RESERVE_BYTES = 1 << 20
#: rosbags 0.11.9 ``McapWriter.write`` closes a chunk by itself above 2**20 bytes; the
#: writer flushes before that so chunk boundaries (= what is durable) stay its own
MAX_CHUNK_BYTES = 1 << 20
_MSG_RECORD_OVERHEAD = 9 + 22  # mcap Message record: opcode + length + header
_MCAP_MSG_RECORD = struct.Struct("<BQHIQQ")  # opcode, length, channel, sequence, log, publish


@functools.lru_cache(maxsize=1)
def jazzy_typestore():
    """The rosbags ROS 2 Jazzy typestore (built once; its classes are shared)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


# ---------------------------------------------------------------------------- QoS
DEFAULT_QOS = {
    "history": "keep_last",
    "depth": 10,
    "reliability": "reliable",
    "durability": "volatile",
    "liveliness": "automatic",
}


def make_qos(profile: Mapping | None = None):
    """A ``rosbags.interfaces.Qos`` from a dict such as ``{"reliability": "best_effort",
    "depth": 5}``; missing keys take :data:`DEFAULT_QOS` (deadline, lifespan and lease
    0 = RMW default)."""
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    p = dict(DEFAULT_QOS)
    if profile:
        unknown = set(profile) - set(DEFAULT_QOS)
        if unknown:
            raise BagError(f"qos: unknown key(s) {sorted(unknown)}; known: {sorted(DEFAULT_QOS)}")
        p.update(profile)

    def enum(cls, key):
        try:
            return cls[str(p[key]).upper()]
        except KeyError:
            raise BagError(
                f"qos.{key}: unknown value {p[key]!r}; expected one of "
                f"{[m.name.lower() for m in cls]}"
            ) from None

    depth = p["depth"]
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
        raise BagError(f"qos.depth: expected a non-negative integer, got {depth!r}")
    zero = QosTime(0, 0)
    return Qos(
        enum(QosHistory, "history"),
        depth,
        enum(QosReliability, "reliability"),
        enum(QosDurability, "durability"),
        zero,
        zero,
        enum(QosLiveliness, "liveliness"),
        zero,
        False,
    )


# --------------------------------------------------------------------- durability helpers
def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.errno is not None:
        name = errno.errorcode.get(exc.errno, str(exc.errno))
        return f"{name}: {exc.strerror or os.strerror(exc.errno)}"
    return f"{type(exc).__name__}: {exc}"


class DiskReserve:
    """A file locked with ``flock`` that holds ``size`` bytes of disk space.

    The lock says "a live process owns this directory": the kernel drops it when the
    process ends, however it ends (also ``kill -9``), so a stale file is recognised by
    :func:`writer_alive`. The bytes are random (a compressing file system cannot shrink
    them) and are given back by :meth:`release` -- first thing on a write error -- so the
    owner can still finish its files on a full disk.
    """

    def __init__(self, path, size: int):
        self.path = Path(path)
        self.size = int(size)
        self._fh = None

    def acquire(self) -> "DiskReserve":
        """Create, lock and fill the file; raises OSError (ENOSPC when there is no room)."""
        fh = open(self.path, "xb")
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            left = self.size
            while left > 0:
                n = min(left, 1 << 16)
                fh.write(os.urandom(n))
                left -= n
            fh.flush()
        except BaseException:
            fh.close()
            with contextlib.suppress(OSError):
                self.path.unlink()
            raise
        self._fh = fh
        return self

    @property
    def held(self) -> bool:
        return self._fh is not None

    def free_space(self) -> bool:
        """Give the space back but keep the lock; True if there was space to give."""
        if self._fh is None:
            return False
        try:
            if os.fstat(self._fh.fileno()).st_size == 0:
                return False
            self._fh.truncate(0)
            self._fh.flush()
        except OSError:
            return False
        return True

    def release(self) -> None:
        """Give the space back and drop the lock (idempotent, never raises)."""
        fh, self._fh = self._fh, None
        if fh is None:
            return
        with contextlib.suppress(OSError):
            self.path.unlink()
        with contextlib.suppress(OSError):
            fh.close()


def writer_alive(lock_path) -> bool:
    """True when a live process holds the :class:`DiskReserve` lock at ``lock_path``."""
    try:
        fh = open(lock_path, "rb")
    except FileNotFoundError:
        return False
    except OSError:
        return True  # cannot tell: assume alive, never repair under a writer
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return True
    finally:
        fh.close()  # closing drops our own lock, if we got it
    return False


def atomic_write_text(path, text: str, fsync: bool = False) -> None:
    """Write ``text`` to ``path`` through ``path.tmp`` + rename: readers see the old or the
    new file, never half of one, and a failed write (disk full) leaves no ``.tmp`` behind.
    Raises OSError."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            if fsync:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    if fsync:
        with contextlib.suppress(OSError):
            fd = os.open(path.parent, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)


def _now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


# ------------------------------------------------------------------------- writer
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
        self._writer = None
        self._connections: dict[str, object] = {}
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
            storage = writer.storage
            if self._mcap:
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

    def __exit__(self, exc_type, exc, tb) -> bool:
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
            state = self._recover(writer)
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
        writer, storage = self._writer, self._writer.storage
        conns: dict = {}
        rec_head = _MCAP_MSG_RECORD.pack
        limit, big = self.chunk_bytes, 2**20
        n = 0
        topic = None
        try:
            for topic, stamp_ns, data in rows:
                cid = conns.get(topic)
                if cid is None:
                    self._topic_type(topic)
                    cid = conns[topic] = self._connections[topic].id
                if isinstance(stamp_ns, float) and not math.isfinite(stamp_ns):
                    raise BagError(
                        f"bag {self.path}: topic {topic!r}: stamp {stamp_ns!r} is not finite"
                    )
                ns = int(stamp_ns)
                if not 0 <= ns < 2**63:
                    raise BagError(
                        f"bag {self.path}: topic {topic!r}: stamp {ns} ns outside [0, 2^63)"
                    )
                size = len(data)
                chunk = storage.chunk
                if chunk.msgs and chunk.bio.tell() + _MSG_RECORD_OVERHEAD + size > limit:
                    self._flush()
                    chunk = storage.chunk
                nchunks = len(storage.chunks)
                # McapWriter.write
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
                bio.write(rec_head(0x05, 22 + size, cid, 0, ns, ns))
                bio.write(data)
                if bio.tell() > big:
                    storage.close_chunk()
                # Writer.write
                writer.counts[cid] += 1
                if ns < writer.min_timestamp:
                    writer.min_timestamp = ns
                if ns > writer.max_timestamp:
                    writer.max_timestamp = ns
                self.counts[topic] += 1
                n += 1
                now = self._clock()
                if not self._pending_n:
                    self._oldest = now
                self._pending_n += 1
                if (
                    len(storage.chunks) != nchunks
                    or self._pending_n >= self.flush_messages
                    or now - self._oldest >= self.flush_interval_s
                ):
                    self._flush()
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

    def _write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        if isinstance(stamp_ns, float) and not math.isfinite(stamp_ns):
            raise BagError(f"bag {self.path}: topic {topic!r}: stamp {stamp_ns!r} is not finite")
        ns = int(stamp_ns)
        if not 0 <= ns < 2**63:
            raise BagError(f"bag {self.path}: topic {topic!r}: stamp {ns} ns outside [0, 2^63)")
        conn = self._connections[topic]
        storage = self._writer.storage
        try:
            if (
                self._mcap
                and storage.chunk.msgs
                and storage.chunk.bio.tell() + _MSG_RECORD_OVERHEAD + len(data) > self.chunk_bytes
            ):
                self._flush()
            nchunks = len(storage.chunks) if self._mcap else 0
            self._writer.write(conn, ns, data)
            self.counts[topic] += 1
            if not self._mcap:
                self._pending_rows.append((conn.id, ns, data))
            now = self._clock()
            if not self._pending_n:
                self._oldest = now
            self._pending_n += 1
            if (
                (self._mcap and len(storage.chunks) != nchunks)
                or self._pending_n >= self.flush_messages
                or now - self._oldest >= self.flush_interval_s
            ):
                self._flush()
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

    def _fail(self, what: str, exc: BaseException):
        """Recover what was written (so it stays readable) and raise a BagError naming the
        path, the error and what is readable."""
        self._failed = f"{what}: {_describe(exc)}"
        writer, self._writer = self._writer, None
        self._closed = True
        state = self._recover(writer) if writer is not None else "bag was not open"
        raise BagError(f"bag {self.path}: {what} ({_describe(exc)}); {state}") from None

    def _recover(self, writer) -> str:
        """After a write/close error: give the disk reserve back, save the messages still
        in memory (the pending mcap chunk, the uncommitted sqlite3 rows), index the file
        and write ``metadata.yaml`` from what it holds (:func:`repair_bag`); set
        ``durable_counts`` to that. Returns a sentence for the error message."""
        if self._reserve is not None:
            self._reserve.release()
        with contextlib.suppress(OSError):
            (self.path / "metadata.yaml.tmp").unlink()
        storage = writer.storage
        try:
            if self._mcap:
                limit = pending = None
                if storage is not None:
                    pending = _pending_chunk(storage)
                    limit = _completed_end(storage, self._header_end)
                    with contextlib.suppress(Exception):
                        storage.bio.close()  # hands over what it can; the walk checks
                rep = repair_bag(self.path, _limit=limit, _pending=pending)
            else:
                if storage is not None:
                    self._settle_sqlite(storage)
                rep = repair_bag(self.path)
        except Exception as exc:  # noqa: BLE001 - the write error is what gets raised
            return (
                f"what reached the disk stays there, but it could not be indexed ({exc}); "
                f"run `lpv-sysid bag repair {self.path}` once there is space"
            )
        self.repair = rep
        self.durable_counts = {
            t: rep.topics[t].count if t in rep.topics else 0 for t in self.counts
        }
        lost = sum(self.counts.values()) - rep.messages
        if lost <= 0:
            return f"closed; all {rep.messages} message(s) written are readable"
        return (
            f"closed; {rep.messages} message(s) readable, the last {lost} written could "
            "not be saved"
        )

    def _settle_sqlite(self, storage) -> None:
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
            if self._pending_rows and have == sum(self.durable_counts.values()):
                conn.executemany(
                    "INSERT INTO messages (topic_id, timestamp, data) VALUES(?, ?, ?)",
                    self._pending_rows,
                )
                conn.commit()
        except sqlite3.Error as exc:
            LOG.error("bag %s: saving the uncommitted rows failed: %s", self.path, exc)
            with contextlib.suppress(sqlite3.Error):
                conn.rollback()
        finally:
            with contextlib.suppress(sqlite3.Error):
                conn.close()


def _pending_chunk(storage):
    """``(records, start_ns, end_ns)`` of the mcap chunk rosbags holds in memory, or None."""
    chunk = storage.chunk
    data = chunk.bio.getvalue()
    if not data:
        return None
    if not chunk.msgs:
        return data, 0, 0
    return data, chunk.message_start_time, chunk.message_end_time


def _completed_end(storage, header_end: int) -> int:
    """File offset after the last chunk (and its message indexes) rosbags finished writing
    to its buffer; beyond it the file holds at most a partial write of the pending chunk."""
    if not storage.chunks:
        return header_end
    rec = storage.chunks[-1].getvalue()  # a ChunkIndex record body
    _t0, _t1, start, length = struct.unpack_from("<QQQQ", rec, 0)
    (map_len,) = struct.unpack_from("<I", rec, 32)
    (index_len,) = struct.unpack_from("<Q", rec, 36 + map_len)
    return start + length + index_len


# ------------------------------------------------------------ CDR block codec
# The messages this package writes have a fixed layout per topic: their strings (frame ids,
# joint names) and sequence lengths do not change from one message to the next, so every
# numeric field sits at the same byte offset of every record. Such records are decoded (and
# encoded) for a whole topic at once as rows of a numpy structured array. The layout of a
# group of records is derived from one of them deserialised by rosbags (the "template") and
# is used only after a probe check: a copy of the template with a distinct value in every
# numeric field is serialised by rosbags and must decode to exactly those values through
# the layout (and encode back to the same bytes). Records whose structural bytes (the CDR
# encapsulation header, string lengths and contents, sequence counts) differ from the
# template's form another group; anything the layout cannot describe goes through
# rosbags' own ``deserialize_cdr``.
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
        for name in self.dtype.names:
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

    def __init__(self):
        self._by_key: dict = {}
        self._bad: set = set()

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


# ------------------------------------------------------------------------- reading
class BagContents(dict):
    """``{topic: [(stamp_ns, msg), ...]}`` plus ``types`` (topic -> msgtype) and
    ``problems`` (what could not be read; empty for a healthy bag)."""

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self.types: dict[str, str] = {}
        self.problems: list[str] = []


class _Source:
    """Raw records of one storage: topic types, definitions and ``(topic, ns, bytes)``."""

    def __init__(self):
        self.types: dict[str, str] = {}
        self.msgdefs: dict[str, str] = {}  # msgtype -> ros2msg definition text
        self.records: list[tuple[str, int, bytes]] = []


def _read_with_rosbags(target: Path, topics: set | None, src: _Source) -> None:
    """Raw records of a healthy bag (directory with metadata.yaml, or a .mcap/.db3 file):
    through the chunk reader of :func:`_read_fast` when it applies, else through AnyReader
    (which also produces the error for a damaged bag)."""
    try:
        _read_fast(target, topics, src)
        return
    except Exception as exc:  # noqa: BLE001 - AnyReader reads it (or names the problem)
        LOG.debug("bag %s: chunk reader not used (%s)", target, _describe(exc))
        src.types.clear()
        src.msgdefs.clear()
        src.records.clear()
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import MessageDefinitionFormat

    with AnyReader([target], default_typestore=jazzy_typestore()) as reader:
        for c in reader.connections:
            src.types[c.topic] = c.msgtype
            if c.msgdef.format == MessageDefinitionFormat.MSG and c.msgdef.data:
                src.msgdefs.setdefault(c.msgtype, c.msgdef.data)
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        if conns:
            for c, ns, data in reader.messages(connections=conns):
                src.records.append((c.topic, ns, data))


# ------------------------------------------------------------------- fast raw reading
# A healthy mcap bag (what BagWriter and ros2 bag record write) is read here without
# rosbags' Reader: its summary section (schemas, channels, chunk indexes, statistics) and
# metadata.yaml (PyYAML's C loader) are parsed directly, chunks are decompressed through
# rosbags' ``decompress`` (size and CRC checked) and their records walked in one loop.
# Anything unusual -- no summary, compression, sqlite3, IDL definitions, topics whose QoS
# or encoding differ between metadata.yaml and the file -- raises _FastPathUnavailable and
# the bag is read by rosbags' AnyReader, which also names the problem of a damaged bag.
_MCAP_OPLEN = struct.Struct("<BQ")
_MCAP_MSG = struct.Struct("<HIQ")  # channel id, sequence, log time
_MCAP_CHUNK_HEAD = struct.Struct("<QQQI")  # start, end, uncompressed size, crc
_MCAP_FOOTER_HEAD = b"\x02\x14\x00\x00\x00\x00\x00\x00\x00"


class _FastPathUnavailable(Exception):
    """The fast reader does not handle this bag; rosbags' AnyReader reads it instead."""


def _yaml_load(text: str):
    """metadata.yaml / QoS text through the package's YAML loader (libyaml parser)."""
    from lpv_sysid.io.yaml_file import strict_load

    return strict_load(text)


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
    with open(path, "rb") as fh:
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
        meta_path = target / "metadata.yaml"
        try:
            info = _yaml_load(meta_path.read_text())["rosbag2_bagfile_information"]
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
        except (OSError, yaml.YAMLError, KeyError, TypeError, AttributeError) as exc:
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


@functools.lru_cache(maxsize=256)
def _definition_ok(msgtype: str, text: str, digest: str) -> bool:
    """AnyReader's check of a stored definition, cached: the ros2msg text parses and, when
    the bag stores a RIHS01 type hash, hashes to it."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(text, msgtype))
    return not digest or store.hash_rihs01(msgtype) == digest


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
    with open(sm.path, "rb") as fh:
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
        with open(sm.path, "rb") as fh:
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


def _salvage_mcap(path: Path, topics: set | None, src: _Source, problems: list) -> None:
    """Complete records of an mcap file rosbags cannot open (no footer: killed writer)."""
    records = []

    def keep(cid, log_time, data):
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


def _salvage_sqlite(path: Path, topics: set | None, src: _Source, problems: list) -> None:
    """Readable rows of a damaged sqlite3 file. A truncated file is first padded (in a
    temporary copy) with zero pages up to the size its header declares: SQLite refuses a
    file shorter than that, while the pages before the cut are intact, so rows are read in
    id order until the first missing page."""
    raw = path.read_bytes()
    if raw[:16] == b"SQLite format 3\x00" and len(raw) >= 32:
        (page,) = struct.unpack(">H", raw[16:18])
        page = 65536 if page == 1 else page
        (npages,) = struct.unpack(">I", raw[28:32])
        if len(raw) < page * npages:
            problems.append(f"{path}: truncated: {len(raw)} of {page * npages} bytes present")
            # Drop the partial last page; fill the missing pages with 0xFF so that any
            # access to them (b-tree page type 0xFF, overflow pointer 0xFFFFFFFF beyond
            # the file) is reported as corruption instead of reading zeros as data.
            keep = raw[: len(raw) // page * page]
            with tempfile.TemporaryDirectory() as tmp:
                padded = Path(tmp) / path.name
                padded.write_bytes(keep + b"\xff" * (page * npages - len(keep)))
                _read_sqlite_rows(padded, path, topics, src, problems)
            return
    _read_sqlite_rows(path, path, topics, src, problems)


def _read_sqlite_rows(
    path: Path, name: Path, topics: set | None, src: _Source, problems: list
) -> None:
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True)
    except sqlite3.Error as exc:
        problems.append(f"{name}: cannot open sqlite3 file: {exc}")
        return
    try:
        try:
            for msgtype, enc, text in con.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
            ):
                if enc == "ros2msg":
                    src.msgdefs.setdefault(msgtype, text)
        except sqlite3.Error as exc:
            problems.append(f"{name}: message definitions unreadable: {exc}")
        try:
            tid = {i: (nm, typ) for i, nm, typ in con.execute("SELECT id, name, type FROM topics")}
        except sqlite3.Error as exc:
            problems.append(f"{name}: topics table unreadable: {exc}")
            return
        for topic_name, typ in tid.values():
            src.types[topic_name] = typ
        cur = con.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id")
        try:
            for t, ns, data in cur:
                topic = tid.get(t, (None,))[0]
                if topic is not None and (topics is None or topic in topics):
                    src.records.append((topic, ns, bytes(data)))
        except sqlite3.Error as exc:
            problems.append(f"{name}: messages table damaged after {len(src.records)} rows: {exc}")
    except sqlite3.Error as exc:
        problems.append(f"{name}: {exc}")
    finally:
        con.close()


def _storage_files(directory: Path) -> list[Path]:
    return sorted(p for p in directory.iterdir() if p.suffix in (".mcap", ".db3"))


@contextlib.contextmanager
def _settled(f: Path, problems: list):
    """``f``, or for a sqlite3 file with a hot journal (writer killed inside a commit) a
    temporary copy in which SQLite rolled the unfinished transaction back: rosbags reads
    with ``immutable=1``, which ignores the journal and could see half a commit."""
    journal = f.with_name(f.name + "-journal")
    if f.suffix != ".db3" or not journal.exists() or journal.stat().st_size == 0:
        yield f
        return
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / f.name
        shutil.copyfile(f, copy)
        shutil.copyfile(journal, Path(tmp) / journal.name)
        try:
            con = sqlite3.connect(str(copy))
            try:
                con.execute("SELECT count(*) FROM sqlite_master").fetchone()
            finally:
                con.close()
            problems.append(f"{f}: uncommitted transaction (hot journal) rolled back in a copy")
        except sqlite3.Error as exc:
            problems.append(f"{f}: hot journal could not be rolled back: {exc}")
        yield copy


def _read_file_tolerant(f: Path, topics: set | None, problems: list) -> _Source:
    with _settled(f, problems) as g:
        src = _Source()
        try:
            _read_with_rosbags(g, topics, src)
            return src
        except Exception as exc:  # noqa: BLE001 - rosbags raises many kinds
            problems.append(f"{f}: {_describe(exc)}")
        src = _Source()
        (_salvage_mcap if f.suffix == ".mcap" else _salvage_sqlite)(g, topics, src, problems)
        return src


def _collect(path, topics, strict: bool) -> tuple[list[_Source], list[str]]:
    path = Path(path)
    want = None if topics is None else set(topics)
    if not path.exists():
        raise BagError(f"bag {path}: does not exist")
    problems: list[str] = []
    if path.is_dir():
        meta = path / "metadata.yaml"
        if meta.exists():
            src = _Source()
            try:
                _read_with_rosbags(path, want, src)
                return [src], problems
            except Exception as exc:  # noqa: BLE001
                why = f"bag {path}: cannot be read ({_describe(exc)}); truncated or corrupt?"
        else:
            why = f"bag {path}: missing metadata.yaml (recording not closed?)"
        if strict:
            raise BagError(
                why + f" -- `lpv-sysid bag repair {path}` makes it readable by standard "
                "tools; read_bag(path, strict=False) recovers what is readable"
            )
        problems.append(why)
        files = _storage_files(path)
        if not files:
            problems.append(f"bag {path}: no .mcap or .db3 storage file")
        return [_read_file_tolerant(f, want, problems) for f in files], problems
    if path.suffix not in (".mcap", ".db3"):
        raise BagError(f"bag {path}: not a bag directory, .mcap or .db3 file")
    if strict:
        src = _Source()
        try:
            with _settled(path, problems) as g:
                _read_with_rosbags(g, want, src)
        except Exception as exc:  # noqa: BLE001
            raise BagError(
                f"bag {path}: cannot be read ({_describe(exc)}); truncated or "
                "corrupt? -- read_bag(path, strict=False) recovers what is readable"
            ) from None
        return [src], problems
    return [_read_file_tolerant(path, want, problems)], problems


def _deserializers(sources: list[_Source]) -> dict[str, object]:
    """msgtype -> typestore: the Jazzy store when the bag's definition equals Jazzy's (or
    the bag has none), else a store built from the definitions stored in the bag."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    jazzy = jazzy_typestore()
    out: dict[str, object] = {}
    custom = None
    for src in sources:
        for msgtype in set(src.types.values()):
            text = src.msgdefs.get(msgtype)
            if msgtype in jazzy.types and (
                not text or jazzy.generate_msgdef(msgtype, ros_version=2)[0] == text
            ):
                out[msgtype] = jazzy
            elif text:
                if custom is None:
                    custom = get_typestore(Stores.EMPTY)
                try:
                    custom.register(get_types_from_msg(text, msgtype))
                    out[msgtype] = custom
                except Exception as exc:  # noqa: BLE001
                    LOG.warning("definition of %s unusable: %s", msgtype, exc)
    return out


def read_bag(
    path, topics: Iterable[str] | None = None, strict: bool = True, optional: Iterable[str] = ()
) -> BagContents:
    """Read a rosbag2 directory (or a bare ``.mcap`` / ``.db3`` file).

    Returns :class:`BagContents` ``{topic: [(stamp_ns, msg), ...]}`` sorted by stamp for
    every topic of the bag (or of ``topics``). ``strict=True`` raises :class:`BagError` on
    a missing/damaged bag and on a requested topic the bag does not have; ``strict=False``
    returns what can be read and lists the problems in ``.problems``. ``optional`` topics
    (with ``topics``) are read when the bag has them and are no error when it does not.
    Only the requested topics are deserialised: fixed-layout records block-wise (the CDR
    block codec, messages constructed from the decoded columns), others by rosbags.
    Messages with equal stamps keep the order of the file.
    """
    optional = [t for t in optional if topics is None or t not in topics]
    topics = None if topics is None else list(topics)
    want = None if topics is None else topics + optional
    try:
        bag = _open_fast(Path(path))
        rows = _rows_from_index(bag, None if want is None else set(want))
        src = _Source()
        src.types, src.msgdefs = dict(bag.types), dict(bag.msgdefs)
        sources, problems = [src], []
    except Exception as exc:  # noqa: BLE001 - the record-level reader decides
        LOG.debug("bag %s: index gather not used (%s)", path, _describe(exc))
        sources, problems = _collect(path, want, strict)
        rows = _rows_from_sources(sources)
    out = BagContents()
    out.problems = problems
    for src in sources:
        for topic, msgtype in src.types.items():
            if topics is None or topic in topics or topic in optional:
                out.types.setdefault(topic, msgtype)
                out.setdefault(topic, [])
    if topics is not None:
        missing = [t for t in topics if t not in out.types]
        if missing:
            msg = f"bag {path}: topic(s) {missing} not in bag; it has {sorted(out.types)}"
            if strict:
                raise BagError(msg)
            problems.append(msg)
            for t in missing:
                out.setdefault(t, [])
    stores = _deserializers(sources)
    bad: dict[str, int] = {}
    for topic, r in rows.items():
        if topic not in out.types:
            continue
        msgtype = out.types[topic]
        store = stores.get(msgtype)
        times_l, order_l, msgs = [], [], []
        odd = r.raw
        if store is not None:
            dec = _decode_rows(store, msgtype, r)
            for times, order, lay, f in dec.parts:
                times_l.append(times)
                order_l.append(order)
                msgs.extend(_builder(store, lay)(f, times.size))
            odd = dec.odd
        items: list = []
        for ns, order, data in odd:
            try:
                if store is None:
                    raise BagError(f"no definition for {msgtype}")
                msg = store.deserialize_cdr(data, msgtype)
            except Exception as exc:  # noqa: BLE001
                if strict:
                    raise BagError(
                        f"bag {path}: topic {topic!r}: message at {ns} ns cannot be "
                        f"deserialised as {msgtype}: {_describe(exc)}"
                    ) from None
                bad[topic] = bad.get(topic, 0) + 1
                continue
            items.append((ns, order, msg))
        if items:
            times_l.append(np.array([it[0] for it in items], np.int64))
            order_l.append(np.array([it[1] for it in items], np.int64))
            msgs.extend(it[2] for it in items)
        if not msgs:
            continue
        times = np.concatenate(times_l)
        idx = np.lexsort((np.concatenate(order_l), times))  # stamp, then file order
        if np.array_equal(idx, np.arange(idx.size)):
            out[topic] = list(zip(times.tolist(), msgs))
        else:
            out[topic] = list(zip(times[idx].tolist(), [msgs[i] for i in idx.tolist()]))
    for topic, n in bad.items():
        problems.append(f"bag {path}: topic {topic!r}: {n} message(s) could not be deserialised")
    for p in problems:
        LOG.warning("%s", p)
    return out


# ------------------------------------------------------------- column-wise decoding
@dataclass
class TopicArrays:
    """One topic decoded column-wise (:func:`read_arrays`).

    ``log_time`` (N,) int64 bag timestamps in ns, sorted (stable: equal stamps keep the
    order of the file); ``fields`` numeric leaf path (``"header.stamp.sec"``,
    ``"pose.pose.position.x"``, ``"velocity"``) -> (N,) or (N, k) array; ``strings`` string
    leaf path (``"header.frame_id"``, ``"name"`` for a string sequence) -> (N,) object array
    of ``str`` (tuples of ``str`` for string sequences). Values are those of rosbags'
    ``deserialize_cdr`` of the same records.
    """

    msgtype: str
    log_time: np.ndarray
    fields: dict
    strings: dict

    def __len__(self) -> int:
        return int(self.log_time.size)


class BagArrays(dict):
    """``{topic: TopicArrays}`` plus ``types`` and ``problems`` (as :class:`BagContents`)."""

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self.types: dict[str, str] = {}
        self.problems: list[str] = []


@dataclass
class _Rows:
    """Records of one topic: per length, a block of rows plus their stamps and file order."""

    blocks: dict = field(default_factory=dict)  # length -> [(times, order, (n, L) uint8)]
    raw: list = field(default_factory=list)  # (time, order, bytes) of odd records

    def add_bytes(self, t: int, order: int, data) -> None:
        self.raw.append((t, order, data))

    def groups(self):
        """(times, order, block) per record length, the odd records folded in."""
        by_len: dict = {}
        for t, o, d in self.raw:
            by_len.setdefault(len(d), []).append((t, o, d))
        for n, items in by_len.items():
            times = np.fromiter((i[0] for i in items), np.int64, len(items))
            order = np.fromiter((i[1] for i in items), np.int64, len(items))
            block = np.frombuffer(b"".join(i[2] for i in items), np.uint8).reshape(len(items), n)
            self.blocks.setdefault(n, []).append((times, order, block))
        self.raw = []
        for n, parts in self.blocks.items():
            if len(parts) == 1:
                yield parts[0]
            else:
                yield (
                    np.concatenate([p[0] for p in parts]),
                    np.concatenate([p[1] for p in parts]),
                    np.concatenate([p[2] for p in parts]),
                )


def _rows_from_index(bag: _FastBag, topics) -> dict[str, _Rows]:
    """Records of the selected topics of a healthy mcap bag, gathered chunk by chunk through
    the message indexes with array indexing (no per-record Python work)."""
    rows: dict[str, _Rows] = {}
    for fno, (sm, cmap) in enumerate(bag.files):
        sel = {cid: t for cid, t in cmap.items() if topics is None or t in topics}
        if not sel:
            continue
        with open(sm.path, "rb") as fh:
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

    def __init__(self):
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
    rows = None
    sources: list = []
    try:
        bag = _open_fast(p)
        rows = _rows_from_index(bag, want)
        types = dict(bag.types)
        msgdefs = dict(bag.msgdefs)
    except Exception as exc:  # noqa: BLE001 - the record-level reader decides
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


def _builder(store, lay: CdrLayout):
    """A function ``build(fields, n) -> [msg, ...]`` constructing ``n`` rosbags messages of
    ``lay``'s shape from decoded columns (what ``deserialize_cdr`` returns, field by field:
    Python scalars, read-only numpy arrays, lists of strings)."""
    key = (
        id(store),
        lay.msgtype,
        lay.size,
        lay.struct_bytes.tobytes(),
        lay.struct_index.tobytes(),
    )
    fn = _BUILDERS.get(key)
    if fn is not None:
        return fn
    from rosbags.interfaces import Nodetype

    ns: dict = {}
    scalars: list = []
    arrays: list = []

    def name_of(obj, prefix):
        k = f"{prefix}{len(ns)}"
        ns[k] = obj
        return k

    def msg_expr(msgtype, prefix):
        cls = name_of(store.types[msgtype], "T")
        parts = [field_expr(desc, prefix + fname) for fname, desc in store.fielddefs[msgtype][1]]
        return f"{cls}({', '.join(parts)})"

    def field_expr(desc, path):
        kind, arg = desc
        if kind == Nodetype.NAME:
            return msg_expr(arg, path + ".")
        if kind == Nodetype.BASE:
            if arg[0] == "string":
                return name_of(lay.strings[path], "S")
            scalars.append(path)
            return f"v{len(scalars) - 1}[i]"
        sub = arg[0] if kind == Nodetype.SEQUENCE else arg[0]
        if sub[0] == Nodetype.BASE and sub[1][0] != "string":
            arrays.append(path)
            return f"a{len(arrays) - 1}[i]"
        if sub[0] == Nodetype.BASE:
            return f"list({name_of(lay.strings[path], 'S')})"
        n = lay.counts[path]
        return "[" + ", ".join(msg_expr(sub[1], f"{path}[{j}].") for j in range(n)) + "]"

    expr = msg_expr(lay.msgtype, "")
    args = [f"v{k}" for k in range(len(scalars))] + [f"a{k}" for k in range(len(arrays))]
    src = f"def build({', '.join(args + ['n'])}):\n    return [{expr} for i in range(n)]\n"
    exec(compile(src, f"<lpv_sysid.io.bag builder {lay.msgtype}>", "exec"), ns)  # noqa: S102
    inner = ns["build"]

    def build(fields_: Mapping, n: int) -> list:
        cols = [fields_[p].tolist() for p in scalars]
        arrs = []
        for p in arrays:
            a = fields_[p]
            a.flags.writeable = False  # rosbags' arrays are read-only views too
            arrs.append(a)
        return inner(*cols, *arrs, n)

    _BUILDERS[key] = build
    return build


@dataclass(frozen=True)
class TopicStats:
    """Per-topic summary of a bag; ``rate_hz = (count - 1) / duration``."""

    msgtype: str
    count: int
    start_ns: int | None
    end_ns: int | None

    @property
    def duration_s(self) -> float:
        if self.start_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / 1e9

    @property
    def rate_hz(self) -> float:
        d = self.duration_s
        return (self.count - 1) / d if self.count > 1 and d > 0 else 0.0


def merge_topic_stats(parts: Iterable[Mapping[str, TopicStats]]) -> dict[str, TopicStats]:
    """Per-topic totals over several bags or files: counts added, time span widened."""
    acc: dict[str, list] = {}
    for part in parts:
        for t, s in part.items():
            a = acc.setdefault(t, [s.msgtype, 0, None, None])
            a[1] += s.count
            if s.count:
                a[2] = s.start_ns if a[2] is None else min(a[2], s.start_ns)
                a[3] = s.end_ns if a[3] is None else max(a[3], s.end_ns)
    return {t: TopicStats(*v) for t, v in acc.items()}


def topic_info(path, strict: bool = True) -> dict[str, TopicStats]:
    """Message counts, types, time spans and mean rates per topic (no deserialisation).

    A healthy indexed mcap bag is answered from its summary and message indexes (16 bytes
    per message, nothing decompressed); anything else is read record by record."""
    p = Path(path)
    if (p.is_dir() and (p / "metadata.yaml").is_file()) or p.suffix == ".mcap":
        try:
            return _topic_info_fast(p)
        except Exception as exc:  # noqa: BLE001 - the record-level path below decides
            LOG.debug("bag %s: index not used for topic_info (%s)", p, _describe(exc))
    sources, _problems = _collect(path, None, strict)
    stats: dict[str, list] = {}
    types: dict[str, str] = {}
    for src in sources:
        for topic, msgtype in src.types.items():
            types.setdefault(topic, msgtype)
            stats.setdefault(topic, [0, None, None])
        for topic, ns, _ in src.records:
            s = stats.setdefault(topic, [0, None, None])
            s[0] += 1
            s[1] = ns if s[1] is None else min(s[1], ns)
            s[2] = ns if s[2] is None else max(s[2], ns)
    return {t: TopicStats(types.get(t, "?"), *s) for t, s in sorted(stats.items())}


# ------------------------------------------------------------------- mcap record walk
# MCAP records are (opcode u8, length u64, body). rosbags 0.11.9 writes: magic, Header,
# then Chunks (its first chunk also holds the Schema and Channel records), each followed
# by one MessageIndex per channel, and at close Metadata, DataEnd, the summary section and
# the Footer. A killed or starved writer leaves the file cut anywhere after a chunk.
_DATA_OPS = frozenset({0x03, 0x04, 0x05, 0x06, 0x07, 0x09, 0x0C})
_END_OPS = frozenset({0x02, 0x08, 0x0A, 0x0B, 0x0D, 0x0E, 0x0F})  # footer / summary / data end


class _Damaged(Exception):
    """A record that cannot be parsed; ends the walk."""


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


def _walk_records(buf, walk: _McapWalk, on_message, where: str):
    """The records inside a chunk: Schema/Channel update ``walk``; Message records go to
    ``on_message(channel_id, log_time, data)``. Returns ``(msgs, nbytes)`` per channel."""
    msgs: dict = {}
    nbytes: dict = {}
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


def _parse_chunk(body: bytes, pos: int, walk: _McapWalk, on_message, where: str) -> _Chunk:
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


def _walk_mcap(path: Path, on_message=None, limit: int | None = None) -> _McapWalk:
    """Walk the data section of an mcap file record by record, never past ``limit`` bytes;
    stops at the end of the data section, at the first incomplete or unreadable record."""
    walk = _McapWalk()
    where = str(path)
    with open(path, "rb") as fh:
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


# ------------------------------------------------------------------------- repair
@dataclass(frozen=True)
class RepairReport:
    """What :func:`repair_bag` found and did.

    ``action``: ``"none"`` (the bag was intact), ``"metadata"`` (only ``metadata.yaml``
    was (re)written) or ``"storage"`` (the storage file was repaired too: an unfinished
    tail cut and the mcap index appended, or an uncommitted sqlite3 transaction rolled
    back). ``topics`` are the readable messages per topic, ``bytes`` their payload.
    """

    path: str
    storage: str
    action: str
    topics: Mapping[str, TopicStats]
    bytes: int = 0
    cut_bytes: int = 0
    notes: tuple[str, ...] = ()
    dry_run: bool = False

    @property
    def messages(self) -> int:
        return sum(s.count for s in self.topics.values())

    @property
    def changed(self) -> bool:
        return self.action != "none"

    def summary(self) -> str:
        what = {
            "none": "intact, nothing to do",
            "metadata": "metadata.yaml regenerated",
            "storage": "storage file repaired and metadata.yaml regenerated",
        }[self.action]
        if self.dry_run and self.changed:
            what = "needs repair: " + what.replace("regenerated", "to regenerate").replace(
                "repaired", "to repair"
            )
        parts = [
            f"{Path(self.path).name}: {self.storage}, {what}",
            f"{self.messages} message(s) readable",
        ]
        if self.cut_bytes:
            parts.append(
                f"{self.cut_bytes} byte(s) of an unfinished write "
                + ("to cut" if self.dry_run else "cut")
            )
        return "; ".join(parts + list(self.notes))


@dataclass
class _FileInfo:
    name: str
    conns: list  # [(topic, msgtype, serialization_format, [Qos], digest, count)]
    topics: dict  # topic -> TopicStats
    bytes: int = 0
    changed: bool = False
    cut: int = 0
    notes: list = field(default_factory=list)

    @property
    def count(self) -> int:
        return sum(s.count for s in self.topics.values())

    @property
    def span(self) -> tuple[int, int] | None:
        spans = [(s.start_ns, s.end_ns) for s in self.topics.values() if s.count]
        if not spans:
            return None
        return min(a for a, _ in spans), max(b for _, b in spans)


def repair_bag(
    path, dry_run: bool = False, *, _limit: int | None = None, _pending=None
) -> RepairReport:
    """Make the rosbag2 directory ``path`` readable by standard tools (``ros2 bag``,
    rosbags' ``AnyReader``), keeping every complete record; see the module docstring.

    Refuses (:class:`BagError`) a bag whose writer is alive, a file that is not an mcap /
    sqlite3 bag or is damaged beyond its tail. ``dry_run`` reports without changing
    anything. (``_limit`` / ``_pending`` are for :class:`BagWriter`'s own recovery: the
    end of what it completed and the chunk it still held in memory.)
    """
    try:
        return _repair_bag(Path(path), dry_run, _limit, _pending)
    except OSError as exc:
        raise BagError(f"bag {path}: repair failed: {_describe(exc)}") from None
    except sqlite3.Error as exc:
        raise BagError(f"bag {path}: repair failed: sqlite3: {exc}") from None


def _repair_bag(path: Path, dry_run: bool, _limit, _pending) -> RepairReport:
    if not path.is_dir():
        raise BagError(f"bag {path}: not a bag directory")
    if writer_alive(path / LOCK_FILE):
        raise BagError(
            f"bag {path}: being written by a running process ({LOCK_FILE} is "
            "locked); stop the recorder first"
        )
    files = _storage_files(path)
    if not files:
        raise BagError(f"bag {path}: no .mcap or .db3 storage file")
    suffixes = {f.suffix for f in files}
    if len(suffixes) > 1:
        raise BagError(f"bag {path}: mixed storage files {[f.name for f in files]}")
    storage = "mcap" if suffixes == {".mcap"} else "sqlite3"
    if not dry_run:  # stale leftovers; the reserve frees room for the repair
        for stale in (path / LOCK_FILE, path / "metadata.yaml.tmp"):
            with contextlib.suppress(FileNotFoundError):
                stale.unlink()
    infos = []
    for i, f in enumerate(files):
        last = i == len(files) - 1
        if storage == "mcap":
            infos.append(
                _repair_mcap_file(f, dry_run, _limit if last else None, _pending if last else None)
            )
        else:
            infos.append(_repair_sqlite_file(f, dry_run))
    if any(i.changed for i in infos):
        action = "storage"
    else:
        action = "none" if _metadata_matches(path, storage, infos) else "metadata"
    notes = [n for i in infos for n in i.notes]
    if action != "none" and not dry_run:
        note = f"{_now_iso()}: repaired by lpv_sysid ({action})"
        try:
            _write_bag_metadata(path, storage, infos, note)
        except OSError as exc:
            raise BagError(f"bag {path}: cannot write metadata.yaml: {_describe(exc)}") from None
        _check_readable(path, infos)
    topics = merge_topic_stats(info.topics for info in infos)
    report = RepairReport(
        str(path),
        storage,
        action,
        dict(sorted(topics.items())),
        sum(i.bytes for i in infos),
        sum(i.cut for i in infos),
        tuple(notes),
        dry_run,
    )
    if report.changed:
        LOG.warning("%s", report.summary())
    return report


def _check_readable(path: Path, infos) -> None:
    """rosbags' AnyReader opens the repaired bag and delivers a message of every topic
    that has some (the metadata's topic entries must match the storage's connections)."""
    from rosbags.highlevel import AnyReader

    try:
        with AnyReader([path], default_typestore=jazzy_typestore()) as reader:
            for c in reader.connections:
                if c.msgcount and next(iter(reader.messages(connections=[c])), None) is None:
                    raise BagError(
                        f"bag {path}: after repair rosbags reads no message of "
                        f"{c.topic} (metadata says {c.msgcount})"
                    )
            total = sum(c.msgcount for c in reader.connections)
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise BagError(f"bag {path}: still unreadable after repair: {_describe(exc)}") from None
    want = sum(i.count for i in infos)
    if total != want:
        raise BagError(
            f"bag {path}: after repair rosbags counts {total} messages, the files hold {want}"
        )


def _rihs01(msgtype: str, encoding: str, text: str) -> str:
    """RIHS01 hash of a stored definition ('' when it cannot be computed)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    jazzy = jazzy_typestore()
    try:
        if msgtype in jazzy.types and jazzy.generate_msgdef(msgtype, ros_version=2)[0] == text:
            return jazzy.hash_rihs01(msgtype)
        if encoding == "ros2msg" and text:
            store = get_typestore(Stores.EMPTY)
            store.register(get_types_from_msg(text, msgtype))
            return store.hash_rihs01(msgtype)
    except Exception:  # noqa: BLE001 - a definition rosbags cannot parse has no hash
        pass
    return ""


def _mcap_info(f: Path, walk: _McapWalk, chunks, changed: bool, cut: int, notes) -> _FileInfo:
    from rosbags.rosbag2.storage_mcap import get_qos

    counts: dict = {}
    spans: dict = {}
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
    conns, topics = [], {}
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
        old = topics.get(topic)
        lo, hi = spans.get(cid, (None, None))
        if old is not None and old.count:
            if n:
                lo, hi = min(lo, old.start_ns), max(hi, old.end_ns)
            else:
                lo, hi = old.start_ns, old.end_ns
        topics[topic] = TopicStats(name, (old.count if old else 0) + n, lo, hi)
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


def _repair_mcap_file(f: Path, dry_run: bool, limit: int | None, pending) -> _FileInfo:
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
        start = f.read_bytes()[:64]
        sig = MCAP_MAGIC + b"\x01"
        if walk.size >= 64 or start[: len(sig)] != sig[: len(start)]:
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
    if pending is not None:
        data, t0, t1 = pending
        try:
            msgs, nbytes = _walk_records(data, walk, None, f"{f.name}: chunk held in memory")
        except _Damaged as exc:
            notes.append(str(exc))
        else:
            body = (
                struct.pack("<QQQI", t0, t1, len(data), 0)
                + _enc_str("")
                + struct.pack("<Q", len(data))
                + data
            )
            start = base + len(old_tail)
            ch = _Chunk(
                start,
                9 + len(body),
                t0,
                t1,
                len(data),
                len(data),
                "",
                msgs,
                nbytes,
                {},
                start + 9 + len(body),
            )
            new_tail = _record(0x06, body) + _index_records(ch, ch.end)
            extra = [ch]
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
        lost = sum(len(v) for v in extra[0].msgs.values())
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


def _write_tail(f: Path, head: bytes, base: int, tail: bytes) -> None:
    """Cut ``f`` at ``base`` and append ``tail`` (``head`` replaces a missing header);
    on failure the file is cut back to ``base`` (what was kept stays, ready for a retry)."""
    with open(f, "r+b") as fh:
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


def _repair_sqlite_file(f: Path, dry_run: bool) -> _FileInfo:
    from rosbags.rosbag2.metadata import parse_qos

    journal = f.with_name(f.name + "-journal")
    hot = journal.exists() and journal.stat().st_size > 0
    notes = []
    with tempfile.TemporaryDirectory() as tmp:
        work = f
        if dry_run and hot:  # roll back in a copy, never in the original
            work = Path(tmp) / f.name
            shutil.copyfile(f, work)
            shutil.copyfile(journal, Path(tmp) / journal.name)
        try:
            con = sqlite3.connect(str(work))  # read-write: SQLite rolls a hot journal back
        except sqlite3.Error as exc:
            raise BagError(f"bag {f.parent}: {f.name}: cannot open: {exc}") from None
        try:
            (check,) = con.execute("PRAGMA quick_check").fetchone()
            if check != "ok":
                raise BagError(
                    f"bag {f.parent}: {f.name} is damaged ({check}); not repairable "
                    "in place -- read_bag(path, strict=False) recovers the "
                    "readable rows"
                )
            cols = {r[1] for r in con.execute("PRAGMA table_info(topics)")}
            qos_col = "offered_qos_profiles" if "offered_qos_profiles" in cols else "''"
            hash_col = "type_description_hash" if "type_description_hash" in cols else "''"
            rows = con.execute(
                f"SELECT id, name, type, serialization_format, {qos_col}, "
                f"{hash_col} FROM topics ORDER BY id"
            ).fetchall()
            stats = {
                tid: (n, lo, hi, nb)
                for tid, n, lo, hi, nb in con.execute(
                    "SELECT topic_id, count(*), min(timestamp), max(timestamp), "
                    "coalesce(sum(length(data)), 0) FROM messages GROUP BY topic_id"
                )
            }
        except sqlite3.Error as exc:
            raise BagError(
                f"bag {f.parent}: {f.name} is damaged ({exc}); not repairable in "
                "place -- read_bag(path, strict=False) recovers the readable "
                "rows"
            ) from None
        finally:
            con.close()
        rolled = hot and not work.with_name(work.name + "-journal").exists()
    if rolled:
        notes.append(
            f"{f.name}: uncommitted transaction rolled back" + (" (in a copy)" if dry_run else "")
        )
    conns, topics, nbytes = [], {}, 0
    for tid, name, typ, fmt, qos, digest in rows:
        n, lo, hi, nb = stats.get(tid, (0, None, None, 0))
        nbytes += nb
        try:
            profiles = parse_qos(qos) if qos else []
        except Exception:  # noqa: BLE001
            profiles = []
        conns.append((name, typ, fmt, profiles, digest or "", n))
        old = topics.get(name)
        if old is not None and old.count:
            lo = old.start_ns if not n else min(lo, old.start_ns)
            hi = old.end_ns if not n else max(hi, old.end_ns)
        topics[name] = TopicStats(typ, (old.count if old else 0) + n, lo, hi)
    return _FileInfo(f.name, conns, topics, nbytes, rolled, 0, notes)


def _metadata_matches(path: Path, storage: str, infos) -> bool:
    """Whether the bag's metadata.yaml names exactly these files and message counts."""
    try:
        with open(path / "metadata.yaml", encoding="utf-8") as fh:
            info = _yaml_load(fh.read())["rosbag2_bagfile_information"]
        if info["storage_identifier"] != storage:
            return False
        if [Path(p).name for p in info["relative_file_paths"]] != [i.name for i in infos]:
            return False
        if info["message_count"] != sum(i.count for i in infos):
            return False
        have = {}
        for t in info["topics_with_message_count"]:
            key = (t["topic_metadata"]["name"], t["topic_metadata"]["type"])
            have[key] = have.get(key, 0) + t["message_count"]
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return False
    want: dict = {}
    for i in infos:
        for topic, typ, _fmt, _qos, _digest, n in i.conns:
            want[(topic, typ)] = want.get((topic, typ), 0) + n
    return have == want


def _write_bag_metadata(path: Path, storage: str, infos, note: str) -> None:
    """``metadata.yaml`` (rosbag2 format version 9, as rosbags' Writer writes it) from what
    the storage files hold."""
    from rosbags.rosbag2.metadata import dump_qos_v9

    merged: dict = {}
    for info in infos:
        for topic, typ, fmt, qos, digest, n in info.conns:
            key = (topic, typ, fmt)
            if key in merged:
                merged[key]["message_count"] += n
            else:
                merged[key] = {
                    "topic_metadata": {
                        "name": topic,
                        "type": typ,
                        "serialization_format": fmt,
                        "offered_qos_profiles": dump_qos_v9(qos),
                        "type_description_hash": digest,
                    },
                    "message_count": n,
                }

    def span(spans):
        spans = [s for s in spans if s is not None]
        if not spans:
            return 2**63 - 1, 0
        lo, hi = min(a for a, _ in spans), max(b for _, b in spans)
        return lo, hi - lo

    start, duration = span([i.span for i in infos])
    files = []
    for i in infos:
        s, d = span([i.span])
        files.append(
            {
                "path": i.name,
                "starting_time": {"nanoseconds_since_epoch": s},
                "duration": {"nanoseconds": d},
                "message_count": i.count,
            }
        )
    meta = {
        "rosbag2_bagfile_information": {
            "version": 9,
            "storage_identifier": storage,
            "relative_file_paths": [i.name for i in infos],
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": sum(i.count for i in infos),
            "topics_with_message_count": list(merged.values()),
            "compression_format": "",
            "compression_mode": "",
            "files": files,
            "custom_data": {"lpv_sysid.repair": note},
            "ros_distro": "rosbags",
        }
    }
    atomic_write_text(path / "metadata.yaml", yaml.safe_dump(meta, sort_keys=False), fsync=True)
