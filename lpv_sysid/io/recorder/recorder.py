""":class:`Recorder`: the data-logger core that records topics to numbered rosbag2
directories and keeps ``experiment.yaml`` current (:func:`write_metadata`); the method is
the :mod:`lpv_sysid.io.recorder` docstring."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import yaml

from lpv_sysid.errors import BagError, ConfigError
from lpv_sysid.io.bag import DiskReserve, now_iso
from lpv_sysid.io.files import atomic_write_text
from lpv_sysid.io.messages import qos_of
from lpv_sysid.io.recorder.config import RecorderConfig
from lpv_sysid.io.recorder.experiment import (
    LOCK_FILE,
    METADATA_FILE,
    METADATA_FORMAT,
    repair_experiment,
)
from lpv_sysid.io.recorder.metadata import BagInfo, TopicStats, settle, static_metadata

LOG = logging.getLogger(__name__)


def _default_writer_factory(path: str, storage: str):
    from lpv_sysid.io.bag import BagWriter

    return BagWriter(path, storage=storage)


@dataclass
class Recorder:
    """Records messages; one instance per experiment directory."""

    config: RecorderConfig
    writer_factory: Callable = _default_writer_factory
    stats: dict = field(default_factory=dict)
    bags: list = field(default_factory=list)
    error: str | None = None
    _writer: Any = None  # a BagWriter (or what writer_factory makes: duck-typed)
    _started_ns: int | None = None
    _stopped_ns: int | None = None
    _wall_start: str = ""
    _wall_stop: str = ""
    _typestore: object = None
    _static_meta: dict = field(default_factory=dict)
    _busy: bool = False
    _exit_code: int | None = None
    _lock: DiskReserve | None = None
    _flushes_seen: int = 0
    rotor_sources: dict = field(default_factory=dict)  # rotor_speeds messages per source

    def __post_init__(self):
        self.stats = {t: TopicStats(m) for t, m in self.config.topics.items()}

    @property
    def out_dir(self) -> Path:
        return Path(self.config.out_dir)

    @property
    def recording(self) -> bool:
        return self._writer is not None

    # -- lifecycle --------------------------------------------------------------------
    def start(self, stamp_ns: int) -> None:
        """Create the experiment directory, the metadata and the first bag."""
        if self._started_ns is not None:
            raise BagError(f"recorder: {self.out_dir} already started")
        out = self.out_dir
        if out.exists() and any(out.iterdir()):
            raise BagError(_occupied(out))
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BagError(f"recorder: cannot create {out}: {exc.strerror or exc}") from None
        self._static_meta = static_metadata(self.config)
        # room for experiment.yaml on a full disk: twice its largest part, plus 64 kB
        reserve = (1 << 16) + 2 * sum(
            len(t.encode()) for t in self._static_meta["config_files"].values()
        )
        try:
            self._lock = DiskReserve(out / LOCK_FILE, reserve).acquire()
        except OSError as exc:
            raise BagError(
                f"recorder: cannot create {out / LOCK_FILE}: {exc.strerror or exc}"
            ) from None
        self._started_ns = int(stamp_ns)
        self._wall_start = now_iso()
        try:
            self._open_next()
        except BagError:
            self._lock.release()
            raise
        write_metadata(self, closed=False)
        LOG.info("recording %d topic(s) to %s", len(self.stats), out)

    def record(self, topic: str, stamp_ns: int, msg) -> None:
        """Write one message (rosbags object or CDR bytes) stamped ``stamp_ns``."""
        self._busy = True
        try:
            self._record(topic, stamp_ns, msg)
        finally:
            self._busy = False
        if self._exit_code is not None:  # a signal arrived during the write
            raise SystemExit(self._exit_code)

    def _record(self, topic: str, stamp_ns: int, msg) -> None:
        if self._writer is None:
            raise BagError(
                f"recorder: {self.out_dir} is not recording"
                + (f" (stopped after error: {self.error})" if self.error else "")
            )
        st = self.stats.get(topic)
        if st is None:
            raise BagError(f"recorder: topic {topic!r} is not configured for recording")
        stamp_ns = int(stamp_ns)
        if self._should_split(stamp_ns):
            self._close_current()
            self._open_next()
            write_metadata(self, closed=False)
        raw = isinstance(msg, (bytes, bytearray, memoryview))
        try:
            if raw:
                nbytes = len(msg)
                self._writer.write_raw(topic, stamp_ns, bytes(msg))
            else:
                nbytes = 0
                self._writer.write(topic, stamp_ns, msg)
        except (OSError, BagError) as exc:
            self._fail(
                f"write of {topic} at {stamp_ns} ns failed: "
                f"{getattr(exc, 'strerror', None) or exc}"
            )
        bag = self.bags[-1]
        if not raw:
            nbytes = self._size_of(msg, st.msgtype)
        bag.bytes += nbytes
        bag.messages += 1
        bag.topics[topic] = bag.topics.get(topic, 0) + 1
        bag.start_ns = stamp_ns if bag.start_ns is None else min(bag.start_ns, stamp_ns)
        bag.end_ns = stamp_ns if bag.end_ns is None else max(bag.end_ns, stamp_ns)
        st.count += 1
        if topic.rsplit("/", 1)[-1] == "rotor_speeds":
            self._note_rotor_source(msg, raw, st.msgtype)
        st.first_ns = stamp_ns if st.first_ns is None else min(st.first_ns, stamp_ns)
        st.last_ns = stamp_ns if st.last_ns is None else max(st.last_ns, stamp_ns)
        self._note_flush()

    def flush_if_due(self) -> bool:
        """Flush the bag when its oldest unflushed message is ``flush_interval_s`` old and
        update ``experiment.yaml`` (for a timer: writes check this themselves, a timer
        covers a stream that stops). True if it flushed."""
        writer = self._writer
        if writer is None or not hasattr(writer, "flush_if_due"):
            return False
        self._busy = True
        try:
            try:
                did = writer.flush_if_due()
            except (OSError, BagError) as exc:
                self._fail(
                    f"flush of {self.bags[-1].path} failed: "
                    f"{getattr(exc, 'strerror', None) or exc}"
                )
            if did:
                self._note_flush()
        finally:
            self._busy = False
        if self._exit_code is not None:
            raise SystemExit(self._exit_code)
        return did

    def split(self) -> str:
        """Close the current bag and open the next one now (one bag per maneuver, e.g. the
        phase-1 campaign of ``lpv-sysid fly``); a bag that holds no message yet is kept, not
        split. Returns the directory name of the bag that records from now on."""
        if self._writer is None:
            raise BagError(
                f"recorder: {self.out_dir} is not recording"
                + (f" (stopped after error: {self.error})" if self.error else "")
            )
        if self.bags[-1].messages:
            self._close_current()
            self._open_next()
            write_metadata(self, closed=False)
        return self.bags[-1].path

    def annotate(self, key: str, value) -> None:
        """Add ``key: value`` (plain YAML data, e.g. the provenance of an imported flight)
        to ``experiment.yaml`` and rewrite it now."""
        if key in ("format", "topics", "bags", "status"):
            raise ConfigError(f"recorder: {key!r} is written by the recorder itself")
        self._static_meta[str(key)] = value
        if self._started_ns is not None:
            write_metadata(self, closed=self._stopped_ns is not None and self.error is None)

    def note_dropped(self, topic: str, count: int = 1) -> None:
        """Messages the middleware reported lost before they reached the logger."""
        if topic in self.stats:
            self.stats[topic].dropped += int(count)

    def stop(self, stamp_ns: int | None = None) -> None:
        """Close the current bag and finalise the metadata (idempotent)."""
        if self._started_ns is None or self._stopped_ns is not None:
            return
        self._stopped_ns = (
            int(stamp_ns)
            if stamp_ns is not None
            else (max((b.end_ns or 0) for b in self.bags) if self.bags else self._started_ns)
        )
        self._wall_stop = now_iso()
        try:
            self._close_current()
        finally:
            write_metadata(self, closed=self.error is None)
            if self._lock is not None:
                self._lock.release()
        LOG.info("recording stopped: %s", self.summary())

    def summary(self) -> str:
        parts = [
            f"{t}: {s.count} msgs {s.rate_hz:.1f} Hz {s.dropped} dropped"
            for t, s in self.stats.items()
        ]
        return f"{len(self.bags)} bag(s) in {self.out_dir}; " + "; ".join(parts)

    # -- internals --------------------------------------------------------------------
    def _should_split(self, stamp_ns: int) -> bool:
        bag = self.bags[-1]
        cfg = self.config
        if bag.messages == 0:
            return False
        if cfg.split_size_bytes and bag.bytes >= cfg.split_size_bytes:
            return True
        if (
            cfg.split_duration_s
            and bag.start_ns is not None
            and stamp_ns - bag.start_ns >= cfg.split_duration_s * 1e9
        ):
            return True
        return False

    def _open_next(self) -> None:
        path = self.out_dir / f"bag_{len(self.bags):04d}"
        try:
            writer = self._make_writer(str(path))
            writer.__enter__()
            for topic, msgtype in self.config.topics.items():
                # the QoS the package's publishers offer (best effort sensors, ...): what
                # ``ros2 bag play`` offers again
                writer.add_topic(topic, msgtype, qos_of(topic))
        except (OSError, BagError) as exc:
            self.error = f"cannot open bag {path}: {getattr(exc, 'strerror', None) or exc}"
            write_metadata(self, closed=False)
            raise BagError(f"recorder: {self.error}") from None
        self._writer = writer
        self._flushes_seen = getattr(writer, "flushes", 0)
        self.bags.append(BagInfo(path=path.name))

    def _make_writer(self, path: str):
        if self.writer_factory is not _default_writer_factory:
            return self.writer_factory(path, self.config.storage)
        from lpv_sysid.io.bag import BagWriter

        c = self.config
        return BagWriter(
            path,
            storage=c.storage,
            flush_interval_s=c.flush_interval_s,
            flush_messages=c.flush_messages,
            fsync=c.fsync,
            reserve_bytes=c.reserve_bytes,
        )

    def _note_flush(self) -> None:
        """After the writer flushed: record what is on disk now and rewrite the metadata."""
        writer = self._writer
        n = getattr(writer, "flushes", None)
        if n is None or n == self._flushes_seen:
            return
        self._flushes_seen = n
        bag = self.bags[-1]
        bag.durable = {
            "topics": dict(writer.durable_counts),
            "bytes": bag.bytes,
            "start_ns": bag.start_ns,
            "end_ns": bag.end_ns,
        }
        write_metadata(self, closed=False)

    def _close_current(self) -> None:
        writer, self._writer = self._writer, None
        if writer is None:
            return
        try:
            writer.__exit__(None, None, None)
        except (OSError, BagError) as exc:
            settle(self.bags[-1], writer)
            msg = f"closing {self.bags[-1].path} failed: {getattr(exc, 'strerror', None) or exc}"
            self.error = self.error or msg
            raise BagError(f"recorder: {msg}") from None
        settle(self.bags[-1], writer)
        self._note_file_bytes(self.bags[-1])

    def _note_file_bytes(self, bag) -> None:
        """``bytes`` of a closed bag: the size of its files on disk (the payload count
        during recording is kept only when splitting by size needs it)."""
        try:
            size = sum(p.stat().st_size for p in (self.out_dir / bag.path).iterdir())
        except OSError:
            return
        if bag.durable is not None:
            bag.durable["bytes"] = int(size)

    def _fail(self, reason: str):
        self.error = reason
        bag = self.bags[-1]
        try:
            self._close_current()
        except BagError:
            pass
        if self._lock is not None:
            self._lock.free_space()  # room for the metadata below, lock kept
        write_metadata(self, closed=False)
        raise BagError(
            f"recorder: {reason}; {bag.path} closed with "
            f"{bag.entry()['messages']} message(s) readable"
        )

    def _note_rotor_source(self, msg, raw: bool, msgtype: str) -> None:
        """Count rotor_speeds per source ("esc" measured / "estimated", io.messages)."""
        from lpv_sysid.io.messages import rotor_source_of

        try:
            src = rotor_source_of(self._ts().deserialize_cdr(bytes(msg), msgtype) if raw else msg)
        except Exception:  # noqa: BLE001 - not a JointState: recorded, source unknown
            src = "unknown"
        self.rotor_sources[src] = self.rotor_sources.get(src, 0) + 1

    def _ts(self):
        if self._typestore is None:
            from rosbags.typesys import Stores, get_typestore

            self._typestore = get_typestore(Stores.ROS2_JAZZY)
        return self._typestore

    def _size_of(self, obj, msgtype: str) -> int:
        if not self.config.split_size_bytes:
            return 0
        return len(self._ts().serialize_cdr(obj, msgtype))


def _occupied(out: Path) -> str:
    """Why ``out`` cannot be recorded into; an interrupted recording there is repaired
    first (the logger's next start is the first chance to do it automatically)."""
    msg = f"recorder: output directory {out} exists and is not empty"
    if not (out / METADATA_FILE).is_file():
        return msg
    try:
        rep = repair_experiment(out)
    except (BagError, ConfigError) as exc:
        return f"{msg} ({exc})"
    if rep.changed:
        return (
            f"{msg}: it held an interrupted recording, now repaired ({rep.summary()}); "
            "choose a new out_dir"
        )
    return msg


def write_metadata(rec: Recorder, closed: bool) -> None:
    """Rewrite ``experiment.yaml`` of ``rec`` atomically (module docstring of
    io/recorder/recorder.py); on a full disk with the lock's reserve freed, else logged."""
    meta = {
        "format": METADATA_FORMAT,
        **rec._static_meta,
        "storage": rec.config.storage,
        "start_time": rec._wall_start,
        "stop_time": rec._wall_stop or None,
        "start_stamp_ns": rec._started_ns,
        "stop_stamp_ns": rec._stopped_ns,
        "status": _status(rec, closed),
        "closed_cleanly": bool(closed),
        "error": rec.error,
        "updated_time": now_iso(),
        "split": {
            "size_bytes": rec.config.split_size_bytes,
            "duration_s": rec.config.split_duration_s,
        },
        "rotor_speeds_source": dict(rec.rotor_sources) or None,  # {"esc"|"estimated": count}
        # counts: what is on disk (committed), never more -- see the module docstring
        "topics": {
            t: {
                "type": s.msgtype,
                "count": _durable_count(rec, t),
                "dropped": s.dropped,
                "rate_hz": round(s.rate_hz, 6),
            }
            for t, s in rec.stats.items()
        },
        "bags": [b.entry() for b in rec.bags],
    }
    path = rec.out_dir / METADATA_FILE
    text = yaml.safe_dump(meta, sort_keys=False)
    try:
        atomic_write_text(path, text, fsync=rec.config.fsync)
    except OSError as exc:
        err = exc  # the last failure (a second one, after the reserve was given back, too)
        if rec._lock is not None and rec._lock.free_space():  # disk full: use the reserve
            try:
                atomic_write_text(path, text, fsync=rec.config.fsync)
                return
            except OSError as exc2:
                err = exc2
        LOG.error("cannot write %s: %s", path, err.strerror or err)


def _status(rec: Recorder, closed: bool) -> str:
    if closed:
        return "closed_cleanly"
    if rec.error is not None or rec._stopped_ns is not None:
        return "incomplete"
    return "recording"


def _durable_count(rec: Recorder, topic: str) -> int:
    return sum((b.durable or {"topics": {}})["topics"].get(topic, 0) for b in rec.bags)
