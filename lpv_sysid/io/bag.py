"""rosbag2 recordings (mcap by default, sqlite3 optional) through rosbags 0.11.9.

Writing
    :class:`BagWriter` is a context manager around ``rosbags.rosbag2.Writer`` (format
    version 9). Messages are CDR-serialised with the ROS 2 Jazzy typestore and each topic
    is registered with its full message definition and RIHS01 type hash, so ``ros2 bag
    info`` / ``ros2 bag play`` accept the result, and with the offered QoS profile
    (default: reliable, volatile, keep-last 10 -- rclpy's default publisher profile).

    rosbags buffers mcap messages in 1 MiB chunks and commits sqlite3 only at close, so a
    crash would lose everything since the last chunk. :meth:`BagWriter.flush` closes the
    pending mcap chunk (or commits sqlite3) and flushes the file; ``chunk_bytes`` sets the
    mcap chunk size. Leaving the ``with`` block -- also through an exception -- closes the
    bag properly (footer, index, ``metadata.yaml``) so what was written stays readable.
    A write error (disk full, ...) raises :class:`BagError` naming the path after the bag
    has been closed (or, when even that fails, aborted with the complete chunks on disk).

Reading
    :func:`read_bag` returns ``{topic: [(stamp_ns, msg), ...]}`` through ``AnyReader``.
    Messages come back sorted by the bag timestamp: rosbag2 allows out-of-order writes
    and stores them as written, but readers (``AnyReader`` and ``ros2 bag play``) deliver
    them in time order. Messages whose definitions equal the Jazzy ones are returned as
    instances of the Jazzy typestore classes (the same classes
    :meth:`lpv_sysid.io.messages.MsgFactory.rosbags` builds).

    A missing ``metadata.yaml`` or a truncated/corrupt storage file raises
    :class:`BagError`; with ``strict=False`` whatever can be read is returned instead and
    the problems are listed in ``result.problems``: the storage file is read directly
    (rosbags reads ``.mcap`` / ``.db3`` files without metadata), and if that fails too, the
    complete records of a truncated mcap are recovered by a record-level scan (rosbags'
    reader needs a valid footer) and the readable rows of a damaged sqlite3 file are read
    with the sqlite3 module.
"""

from __future__ import annotations

import errno
import functools
import logging
import math
import os
import sqlite3
import struct
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

from lpv_sysid.errors import BagError

LOG = logging.getLogger(__name__)

__all__ = ["BagWriter", "BagContents", "TopicStats", "read_bag", "topic_info",
           "jazzy_typestore", "DEFAULT_QOS", "make_qos"]

STORAGES = ("mcap", "sqlite3")
MCAP_MAGIC = b"\x89MCAP0\r\n"


@functools.lru_cache(maxsize=1)
def jazzy_typestore():
    """The rosbags ROS 2 Jazzy typestore (built once; its classes are shared)."""
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


# ---------------------------------------------------------------------------- QoS
DEFAULT_QOS = {"history": "keep_last", "depth": 10, "reliability": "reliable",
               "durability": "volatile", "liveliness": "automatic"}


def make_qos(profile: Mapping | None = None):
    """A ``rosbags.interfaces.Qos`` from a dict such as ``{"reliability": "best_effort",
    "depth": 5}``; missing keys take :data:`DEFAULT_QOS` (deadline, lifespan and lease
    0 = RMW default)."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)
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
            raise BagError(f"qos.{key}: unknown value {p[key]!r}; expected one of "
                           f"{[m.name.lower() for m in cls]}") from None

    depth = p["depth"]
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
        raise BagError(f"qos.depth: expected a non-negative integer, got {depth!r}")
    zero = QosTime(0, 0)
    return Qos(enum(QosHistory, "history"), depth, enum(QosReliability, "reliability"),
               enum(QosDurability, "durability"), zero, zero, enum(QosLiveliness, "liveliness"),
               zero, False)


# ------------------------------------------------------------------------- writer
class BagWriter:
    """rosbag2 writer: ``with BagWriter(path) as bag: bag.add_topic(...); bag.write(...)``.

    ``path`` is the bag directory to create (it must not exist). ``storage`` is ``"mcap"``
    (default) or ``"sqlite3"``.
    """

    def __init__(self, path, storage: str = "mcap", *, typestore=None,
                 chunk_bytes: int = 1 << 20):
        if storage not in STORAGES:
            raise BagError(f"bag {path}: storage must be one of {STORAGES}, got {storage!r}")
        if chunk_bytes <= 0:
            raise BagError(f"bag {path}: chunk_bytes must be positive, got {chunk_bytes}")
        self.path = Path(path)
        self.storage = storage
        self.chunk_bytes = int(chunk_bytes)
        self.typestore = typestore if typestore is not None else jazzy_typestore()
        self.counts: dict[str, int] = {}
        self.types: dict[str, str] = {}
        self._writer = None
        self._connections: dict[str, object] = {}
        self._closed = False
        self._failed: str | None = None

    # -- lifecycle ---------------------------------------------------------------
    def open(self) -> "BagWriter":
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
        if self._writer is not None or self._closed:
            raise BagError(f"bag {self.path}: already opened")
        plugin = StoragePlugin.MCAP if self.storage == "mcap" else StoragePlugin.SQLITE3
        try:
            writer = Writer(self.path, version=9, storage_plugin=plugin)
            writer.open()
        except WriterError as exc:
            raise BagError(f"bag {self.path}: cannot create: {exc}") from None
        except OSError as exc:
            raise BagError(f"bag {self.path}: cannot create: {exc.strerror or exc}") from None
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

    def close(self) -> None:
        """Write index, footer and ``metadata.yaml``; idempotent."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        self._closed = True
        try:
            writer.close()
        except Exception as exc:  # noqa: BLE001 - every failure must become a BagError
            self._salvage_close(writer)
            raise BagError(f"bag {self.path}: closing failed ({_describe(exc)}); what reached "
                           "the disk can be recovered with read_bag(path, strict=False)") from None
        LOG.info("closed bag %s (%d messages)", self.path, sum(self.counts.values()))

    def _salvage_close(self, writer) -> None:
        """After a failed close: keep what is on disk. rosbags' ``abort`` would roll back
        the uncommitted sqlite3 transaction (= every message), so sqlite3 is committed
        instead; for mcap the file is closed as is (complete chunks stay readable)."""
        storage = getattr(writer, "storage", None)
        try:
            if self.storage == "sqlite3" and storage is not None:
                try:
                    storage.conn.commit()
                finally:
                    storage.conn.close()
                writer.storage = None
            else:
                writer.abort()
        except Exception as exc:  # noqa: BLE001
            LOG.error("bag %s: cleanup after failed close: %s", self.path, _describe(exc))

    # -- topics and messages -----------------------------------------------------------
    def add_topic(self, topic: str, msgtype: str, qos: Mapping | None = None) -> None:
        """Register ``topic`` with type ``pkg/msg/Name`` and its offered QoS profile."""
        self._check_open()
        if not isinstance(topic, str) or not topic:
            raise BagError(f"bag {self.path}: topic name must be a non-empty string, got {topic!r}")
        if topic in self._connections:
            if self.types[topic] != msgtype:
                raise BagError(f"bag {self.path}: topic {topic!r} already registered as "
                               f"{self.types[topic]}, not {msgtype}")
            return
        if msgtype not in self.typestore.types:
            raise BagError(f"bag {self.path}: topic {topic!r}: unknown message type {msgtype!r}")
        try:
            conn = self._writer.add_connection(topic, msgtype, typestore=self.typestore,
                                               offered_qos_profiles=[make_qos(qos)])
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001
            self._fail(f"registering topic {topic!r} failed", exc)
        self._connections[topic] = conn
        self.types[topic] = msgtype
        self.counts[topic] = 0

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
            raise BagError(f"bag {self.path}: topic {topic!r}: cannot serialise message as "
                           f"{msgtype}: {_describe(exc)}") from None
        self._write(topic, stamp_ns, data)

    def write_raw(self, topic: str, stamp_ns: int, data: bytes) -> None:
        """Write an already CDR-serialised message (e.g. from a ``raw=True`` subscription)."""
        self._topic_type(topic)
        self._write(topic, stamp_ns, bytes(data))

    def flush(self, fsync: bool = False) -> None:
        """Make everything written so far durable: close the pending mcap chunk / commit
        sqlite3, flush the file (and ``fsync`` it when asked).

        Relies on the storage attributes of rosbags 0.11.9 (``McapWriter.chunk``,
        ``close_chunk``, ``bio``; ``Sqlite3Writer.conn``).
        """
        self._check_open()
        storage = self._writer.storage
        try:
            if self.storage == "mcap":
                if storage.chunk.msgs:
                    storage.close_chunk()
                storage.bio.flush()
                if fsync:
                    os.fsync(storage.bio.fileno())
            else:
                storage.conn.commit()
        except Exception as exc:  # noqa: BLE001
            self._fail("flush failed", exc)

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
            raise BagError(f"bag {self.path}: topic {topic!r} was not added "
                           f"(add_topic first); known: {sorted(self.types)}") from None

    def _write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        if isinstance(stamp_ns, float) and not math.isfinite(stamp_ns):
            raise BagError(f"bag {self.path}: topic {topic!r}: stamp {stamp_ns!r} is not finite")
        ns = int(stamp_ns)
        if not 0 <= ns < 2**63:
            raise BagError(f"bag {self.path}: topic {topic!r}: stamp {ns} ns outside [0, 2^63)")
        try:
            self._writer.write(self._connections[topic], ns, data)
            if self.storage == "mcap" and self._writer.storage.chunk.bio.tell() > self.chunk_bytes:
                self._writer.storage.close_chunk()
        except Exception as exc:  # noqa: BLE001
            self._fail(f"writing {topic!r} failed", exc)
        self.counts[topic] += 1

    def _fail(self, what: str, exc: BaseException):
        """Close what was written (so it stays readable) and raise a BagError naming the path."""
        self._failed = f"{what}: {_describe(exc)}"
        try:
            self.close()
            state = "closed; messages written before the error are readable"
        except BagError as close_exc:
            state = str(close_exc)
        raise BagError(f"bag {self.path}: {what} ({_describe(exc)}); {state}") from None


def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.errno is not None:
        name = errno.errorcode.get(exc.errno, str(exc.errno))
        return f"{name}: {exc.strerror or os.strerror(exc.errno)}"
    return f"{type(exc).__name__}: {exc}"


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
        self.msgdefs: dict[str, str] = {}         # msgtype -> ros2msg definition text
        self.records: list[tuple[str, int, bytes]] = []


def _read_with_rosbags(target: Path, topics: set | None, src: _Source) -> None:
    """Raw records via AnyReader (directory with metadata.yaml, or a .mcap/.db3 file)."""
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


def _read_str(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end = pos + 4 + n
    if end > len(buf):
        raise struct.error("string beyond record")
    return buf[pos + 4:end].decode("utf-8"), end


def _scan_mcap_records(buf: bytes, src: _Source, schemas: dict, channels: dict,
                       topics: set | None, problems: list, where: str, top: bool) -> None:
    """Walk MCAP records (op u8, length u64, body); stops at the first incomplete record.

    Written here because rosbags' McapReader refuses a file without a valid footer.
    """
    pos = len(MCAP_MAGIC) if top else 0
    n = len(buf)
    while pos < n:
        if pos + 9 > n:
            problems.append(f"{where}: truncated record header at byte {pos}")
            return
        op = buf[pos]
        (length,) = struct.unpack_from("<Q", buf, pos + 1)
        body_start, body_end = pos + 9, pos + 9 + length
        if body_end > n:
            problems.append(f"{where}: truncated record (op 0x{op:02x}) at byte {pos}: "
                            f"{n - body_start} of {length} bytes present")
            return
        body = buf[body_start:body_end]
        pos = body_end
        try:
            if op == 0x03:      # Schema
                (sid,) = struct.unpack_from("<H", body, 0)
                name, p = _read_str(body, 2)
                enc, p = _read_str(body, p)
                (dlen,) = struct.unpack_from("<I", body, p)
                schemas[sid] = (name, enc, body[p + 4:p + 4 + dlen].decode("utf-8"))
            elif op == 0x04:    # Channel
                cid, sid = struct.unpack_from("<HH", body, 0)
                topic, _ = _read_str(body, 4)
                channels[cid] = (topic, sid)
                if sid in schemas:
                    name, enc, data = schemas[sid]
                    src.types[topic] = name
                    if enc == "ros2msg":
                        src.msgdefs.setdefault(name, data)
            elif op == 0x05:    # Message
                cid, _seq, log_time = struct.unpack_from("<HIQ", body, 0)
                ch = channels.get(cid)
                if ch is None:
                    problems.append(f"{where}: message on unknown channel {cid} skipped")
                elif topics is None or ch[0] in topics:
                    src.records.append((ch[0], log_time, bytes(body[22:])))
            elif op == 0x06 and top:   # Chunk
                _t0, _t1, usize, crc = struct.unpack_from("<QQQI", body, 0)
                comp, p = _read_str(body, 28)
                (clen,) = struct.unpack_from("<Q", body, p)
                payload = body[p + 8:p + 8 + clen]
                if comp:
                    from rosbags.rosbag2.storage_mcap import decompress
                    payload = decompress(payload, comp, usize, crc)
                _scan_mcap_records(payload, src, schemas, channels, topics, problems,
                                   f"{where} chunk", top=False)
            elif op == 0x02:    # Footer
                return
        except Exception as exc:  # noqa: BLE001 - a damaged record ends the scan
            problems.append(f"{where}: unreadable record (op 0x{op:02x}) before byte {pos}: "
                            f"{_describe(exc)}")
            return


def _salvage_mcap(path: Path, topics: set | None, src: _Source, problems: list) -> None:
    buf = path.read_bytes()
    if not buf.startswith(MCAP_MAGIC):
        problems.append(f"{path}: not an mcap file (bad magic)")
        return
    _scan_mcap_records(buf, src, {}, {}, topics, problems, str(path), top=True)


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


def _read_sqlite_rows(path: Path, name: Path, topics: set | None, src: _Source,
                      problems: list) -> None:
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True)
    except sqlite3.Error as exc:
        problems.append(f"{name}: cannot open sqlite3 file: {exc}")
        return
    try:
        try:
            for msgtype, enc, text in con.execute(
                    "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"):
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


def _read_file_tolerant(f: Path, topics: set | None, problems: list) -> _Source:
    src = _Source()
    try:
        _read_with_rosbags(f, topics, src)
        return src
    except Exception as exc:  # noqa: BLE001 - rosbags raises many kinds
        problems.append(f"{f}: {_describe(exc)}")
    src = _Source()
    (_salvage_mcap if f.suffix == ".mcap" else _salvage_sqlite)(f, topics, src, problems)
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
            raise BagError(why + " -- read_bag(path, strict=False) recovers what is readable")
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
            _read_with_rosbags(path, want, src)
        except Exception as exc:  # noqa: BLE001
            raise BagError(f"bag {path}: cannot be read ({_describe(exc)}); truncated or "
                           "corrupt? -- read_bag(path, strict=False) recovers what is readable") from None
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
            if msgtype in jazzy.types and (not text or
                                           jazzy.generate_msgdef(msgtype, ros_version=2)[0] == text):
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


def read_bag(path, topics: Iterable[str] | None = None, strict: bool = True,
             optional: Iterable[str] = ()) -> BagContents:
    """Read a rosbag2 directory (or a bare ``.mcap`` / ``.db3`` file).

    Returns :class:`BagContents` ``{topic: [(stamp_ns, msg), ...]}`` sorted by stamp for
    every topic of the bag (or of ``topics``). ``strict=True`` raises :class:`BagError` on
    a missing/damaged bag and on a requested topic the bag does not have; ``strict=False``
    returns what can be read and lists the problems in ``.problems``. ``optional`` topics
    (with ``topics``) are read when the bag has them and are no error when it does not.
    Only the requested topics are deserialised.
    """
    optional = [t for t in optional if topics is None or t not in topics]
    topics = None if topics is None else list(topics)
    sources, problems = _collect(path, None if topics is None else topics + optional, strict)
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
    for src in sources:
        for topic, ns, data in src.records:
            msgtype = out.types[topic]
            store = stores.get(msgtype)
            try:
                if store is None:
                    raise BagError(f"no definition for {msgtype}")
                msg = store.deserialize_cdr(data, msgtype)
            except Exception as exc:  # noqa: BLE001
                if strict:
                    raise BagError(f"bag {path}: topic {topic!r}: message at {ns} ns cannot be "
                                   f"deserialised as {msgtype}: {_describe(exc)}") from None
                bad[topic] = bad.get(topic, 0) + 1
                continue
            out[topic].append((ns, msg))
    for topic, n in bad.items():
        problems.append(f"bag {path}: topic {topic!r}: {n} message(s) could not be deserialised")
    for topic in out:
        out[topic].sort(key=lambda item: item[0])     # stable: equal stamps keep bag order
    for p in problems:
        LOG.warning("%s", p)
    return out


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


def topic_info(path, strict: bool = True) -> dict[str, TopicStats]:
    """Message counts, types, time spans and mean rates per topic (no deserialisation)."""
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
