"""Data-logger core: records topics to numbered rosbag2 directories with experiment metadata.

Layout of an experiment directory ``out``::

    out/experiment.yaml        metadata (config files, gains sha256, git revision, times,
                               per-topic counts / rates / drops, bags, clean close, error)
    out/bag_0000/              rosbag2 (mcap by default) written by io/bag.BagWriter
    out/bag_0001/              next split (size or duration limit reached)

Messages arrive as rosbags message objects or as serialized CDR bytes (the node shell
subscribes with ``raw=True``; bytes go to the bag untouched, as ``ros2 bag record`` does).
``experiment.yaml`` is rewritten at start, at every split and at stop, so a crash still
leaves it describing every bag closed so far (``closed_cleanly: false``). A write error
(disk full, ...) closes the current bag so what was written stays readable, is recorded
in the metadata and raised as :class:`~lpv_sysid.errors.BagError`.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import logging
import os
import signal
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping

import yaml

from lpv_sysid.errors import BagError, ConfigError

LOG = logging.getLogger(__name__)
METADATA_FORMAT = "lpv_sysid/experiment@1"
METADATA_FILE = "experiment.yaml"


@dataclass(frozen=True)
class RecorderConfig:
    """What to record and how to split it.

    ``topics`` maps a topic name to its type ``pkg/msg/Name``. ``split_size_bytes`` /
    ``split_duration_s``: start a new bag directory when the current one holds this many
    payload bytes / this much recorded time (0 disables). ``config_files`` are copied
    verbatim into the metadata; ``gains_file`` is hashed (sha256).
    """

    out_dir: str
    topics: Mapping[str, str]
    storage: str = "mcap"
    split_size_bytes: int = 0
    split_duration_s: float = 0.0
    config_files: tuple[str, ...] = ()
    gains_file: str = ""
    description: str = ""

    def __post_init__(self):
        if not self.out_dir:
            raise ConfigError("recorder: out_dir must not be empty")
        if not self.topics:
            raise ConfigError("recorder: topics must list at least one topic")
        for topic, msgtype in self.topics.items():
            if not isinstance(topic, str) or not topic.startswith("/"):
                raise ConfigError(f"recorder: topic {topic!r} must be an absolute name")
            if not isinstance(msgtype, str) or msgtype.count("/") != 2:
                raise ConfigError(f"recorder: topics[{topic!r}] type {msgtype!r} is not "
                                  "'pkg/msg/Name'")
        if self.storage not in ("mcap", "sqlite3"):
            raise ConfigError(f"recorder: storage must be 'mcap' or 'sqlite3', "
                              f"got {self.storage!r}")
        if self.split_size_bytes < 0:
            raise ConfigError("recorder: split_size_bytes must be >= 0")
        if self.split_duration_s < 0:
            raise ConfigError("recorder: split_duration_s must be >= 0")

    @classmethod
    def from_dict(cls, d: Mapping) -> "RecorderConfig":
        known = set(cls.__dataclass_fields__)
        bad = set(d) - known
        if bad:
            raise ConfigError(f"recorder: unknown key(s) {sorted(bad)}")
        for req in ("out_dir", "topics"):
            if req not in d:
                raise ConfigError(f"recorder: missing key '{req}'")
        kw = dict(d)
        kw["topics"] = dict(kw["topics"])
        kw["config_files"] = tuple(kw.get("config_files", ()))
        return cls(**kw)


@dataclass
class TopicStats:
    msgtype: str
    count: int = 0
    dropped: int = 0
    first_ns: int | None = None
    last_ns: int | None = None

    @property
    def rate_hz(self) -> float:
        if self.count < 2 or self.last_ns == self.first_ns:
            return 0.0
        return (self.count - 1) / ((self.last_ns - self.first_ns) * 1e-9)


@dataclass
class _BagInfo:
    path: str
    start_ns: int | None = None
    end_ns: int | None = None
    messages: int = 0
    bytes: int = 0


def git_revision(path: str | os.PathLike) -> str | None:
    """``git rev-parse HEAD`` of the repository containing ``path`` (None when unavailable)."""
    try:
        out = subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], check=True,
                             capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 16), b""):
            h.update(chunk)
    return h.hexdigest()


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
    _writer: object = None
    _started_ns: int | None = None
    _stopped_ns: int | None = None
    _wall_start: str = ""
    _wall_stop: str = ""
    _typestore: object = None
    _static_meta: dict = field(default_factory=dict)
    _busy: bool = False
    _exit_code: int | None = None

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
            raise BagError(f"recorder: output directory {out} exists and is not empty")
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BagError(f"recorder: cannot create {out}: {exc.strerror or exc}") from None
        self._static_meta = self._collect_static_metadata()
        self._started_ns = int(stamp_ns)
        self._wall_start = _now_iso()
        self._open_next()
        self._write_metadata(closed=False)
        LOG.info("recording %d topic(s) to %s", len(self.stats), out)

    def record(self, topic: str, stamp_ns: int, msg) -> None:
        """Write one message (rosbags object or CDR bytes) stamped ``stamp_ns``."""
        self._busy = True
        try:
            self._record(topic, stamp_ns, msg)
        finally:
            self._busy = False
        if self._exit_code is not None:      # a signal arrived during the write
            raise SystemExit(self._exit_code)

    def _record(self, topic: str, stamp_ns: int, msg) -> None:
        if self._writer is None:
            raise BagError(f"recorder: {self.out_dir} is not recording"
                           + (f" (stopped after error: {self.error})" if self.error else ""))
        st = self.stats.get(topic)
        if st is None:
            raise BagError(f"recorder: topic {topic!r} is not configured for recording")
        stamp_ns = int(stamp_ns)
        if self._should_split(stamp_ns):
            self._close_current()
            self._open_next()
            self._write_metadata(closed=False)
        raw = isinstance(msg, (bytes, bytearray, memoryview))
        try:
            if raw:
                nbytes = len(msg)
                self._writer.write_raw(topic, stamp_ns, bytes(msg))
            else:
                nbytes = 0
                self._writer.write(topic, stamp_ns, msg)
        except (OSError, BagError) as exc:
            self._fail(f"write of {topic} at {stamp_ns} ns failed: "
                       f"{getattr(exc, 'strerror', None) or exc}")
        bag = self.bags[-1]
        if not raw:
            nbytes = self._size_of(msg, st.msgtype)
        bag.bytes += nbytes
        bag.messages += 1
        bag.start_ns = stamp_ns if bag.start_ns is None else min(bag.start_ns, stamp_ns)
        bag.end_ns = stamp_ns if bag.end_ns is None else max(bag.end_ns, stamp_ns)
        st.count += 1
        st.first_ns = stamp_ns if st.first_ns is None else min(st.first_ns, stamp_ns)
        st.last_ns = stamp_ns if st.last_ns is None else max(st.last_ns, stamp_ns)

    def note_dropped(self, topic: str, count: int = 1) -> None:
        """Messages the middleware reported lost before they reached the logger."""
        if topic in self.stats:
            self.stats[topic].dropped += int(count)

    def stop(self, stamp_ns: int | None = None) -> None:
        """Close the current bag and finalise the metadata (idempotent)."""
        if self._started_ns is None or self._stopped_ns is not None:
            return
        self._stopped_ns = int(stamp_ns) if stamp_ns is not None else (
            max((b.end_ns or 0) for b in self.bags) if self.bags else self._started_ns)
        self._wall_stop = _now_iso()
        self._close_current()
        self._write_metadata(closed=self.error is None)
        LOG.info("recording stopped: %s", self.summary())

    def summary(self) -> str:
        parts = [f"{t}: {s.count} msgs {s.rate_hz:.1f} Hz {s.dropped} dropped"
                 for t, s in self.stats.items()]
        return f"{len(self.bags)} bag(s) in {self.out_dir}; " + "; ".join(parts)

    # -- internals --------------------------------------------------------------------
    def _should_split(self, stamp_ns: int) -> bool:
        bag = self.bags[-1]
        cfg = self.config
        if bag.messages == 0:
            return False
        if cfg.split_size_bytes and bag.bytes >= cfg.split_size_bytes:
            return True
        if cfg.split_duration_s and bag.start_ns is not None and \
                stamp_ns - bag.start_ns >= cfg.split_duration_s * 1e9:
            return True
        return False

    def _open_next(self) -> None:
        path = self.out_dir / f"bag_{len(self.bags):04d}"
        try:
            writer = self.writer_factory(str(path), self.config.storage)
            writer.__enter__()
            for topic, msgtype in self.config.topics.items():
                writer.add_topic(topic, msgtype)
        except (OSError, BagError) as exc:
            self.error = f"cannot open bag {path}: {getattr(exc, 'strerror', None) or exc}"
            self._write_metadata(closed=False)
            raise BagError(f"recorder: {self.error}") from None
        self._writer = writer
        self.bags.append(_BagInfo(path=path.name))

    def _close_current(self) -> None:
        writer, self._writer = self._writer, None
        if writer is None:
            return
        try:
            writer.__exit__(None, None, None)
        except (OSError, BagError) as exc:
            msg = f"closing {self.bags[-1].path} failed: {getattr(exc, 'strerror', None) or exc}"
            self.error = self.error or msg
            raise BagError(f"recorder: {msg}") from None

    def _fail(self, reason: str):
        self.error = reason
        bag = self.bags[-1]
        try:
            self._close_current()
        except BagError:
            pass
        self._write_metadata(closed=False)
        raise BagError(f"recorder: {reason}; {bag.path} closed with {bag.messages} "
                       "message(s) written before the error")

    def _ts(self):
        if self._typestore is None:
            from rosbags.typesys import Stores, get_typestore
            self._typestore = get_typestore(Stores.ROS2_JAZZY)
        return self._typestore

    def _size_of(self, obj, msgtype: str) -> int:
        if not self.config.split_size_bytes:
            return 0
        return len(self._ts().serialize_cdr(obj, msgtype))

    def _collect_static_metadata(self) -> dict:
        cfg = self.config
        files = {}
        for path in cfg.config_files:
            try:
                files[str(path)] = Path(path).read_text()
            except OSError as exc:
                raise ConfigError(f"recorder: config file {path}: "
                                  f"{exc.strerror or exc}") from None
        gains = None
        if cfg.gains_file:
            try:
                gains = {"path": str(cfg.gains_file), "sha256": sha256_file(cfg.gains_file)}
            except OSError as exc:
                raise ConfigError(f"recorder: gains file {cfg.gains_file}: "
                                  f"{exc.strerror or exc}") from None
        here = Path(__file__).resolve().parent
        return {"description": cfg.description, "config_files": files, "gains": gains,
                "git_revision": git_revision(here)}

    def _write_metadata(self, closed: bool) -> None:
        meta = {
            "format": METADATA_FORMAT,
            **self._static_meta,
            "storage": self.config.storage,
            "start_time": self._wall_start,
            "stop_time": self._wall_stop or None,
            "start_stamp_ns": self._started_ns,
            "stop_stamp_ns": self._stopped_ns,
            "closed_cleanly": bool(closed),
            "error": self.error,
            "split": {"size_bytes": self.config.split_size_bytes,
                      "duration_s": self.config.split_duration_s},
            "topics": {t: {"type": s.msgtype, "count": s.count, "dropped": s.dropped,
                           "rate_hz": round(s.rate_hz, 6)} for t, s in self.stats.items()},
            "bags": [{"path": b.path, "messages": b.messages, "bytes": b.bytes,
                      "start_ns": b.start_ns, "end_ns": b.end_ns} for b in self.bags],
        }
        path = self.out_dir / METADATA_FILE
        tmp = path.with_suffix(".yaml.tmp")
        try:
            tmp.write_text(yaml.safe_dump(meta, sort_keys=False))
            os.replace(tmp, path)
        except OSError as exc:
            LOG.error("cannot write %s: %s", path, exc.strerror or exc)


def _now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


@contextlib.contextmanager
def stop_on_signals(recorder: Recorder, stamp_ns: Callable[[], int] | None = None,
                    signals=(signal.SIGINT, signal.SIGTERM)):
    """Close ``recorder`` cleanly on SIGINT/SIGTERM, then exit (status 128 + signo).

    For processes that own the recorder without rclpy's signal handling (tests, CLI).
    """
    previous = {}

    def handler(signo, _frame):
        # Never close the bag from inside a half-done write: if the signal interrupted
        # record(), it exits once that message is complete; the finally below closes.
        recorder._exit_code = 128 + signo
        if not recorder._busy:
            raise SystemExit(128 + signo)

    for s in signals:
        previous[s] = signal.signal(s, handler)
    try:
        yield recorder
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        recorder.stop(stamp_ns() if stamp_ns else None)
