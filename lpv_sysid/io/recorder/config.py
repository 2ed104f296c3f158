"""What a data-logger :class:`~lpv_sysid.io.recorder.Recorder` records and how it splits
and flushes its bags: :class:`RecorderConfig`, validated."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.bag import FLUSH_INTERVAL_S, FLUSH_MESSAGES, RESERVE_BYTES


@dataclass(frozen=True)
class RecorderConfig:
    """What to record and how to split it.

    ``topics`` maps a topic name to its type ``pkg/msg/Name``. ``split_size_bytes`` /
    ``split_duration_s``: start a new bag directory when the current one holds this many
    payload bytes / this much recorded time (0 disables). ``config_files`` are copied
    verbatim into the metadata; ``gains_file`` is hashed (sha256). Durability
    (:class:`~lpv_sysid.io.bag.BagWriter`): ``flush_interval_s`` (0 < s <= 1) and
    ``flush_messages`` bound what a killed process loses, ``fsync`` makes each flush
    survive a power cut, ``reserve_bytes`` are kept free per bag for closing on a full disk.
    """

    out_dir: str
    topics: Mapping[str, str]
    storage: str = "mcap"
    split_size_bytes: int = 0
    split_duration_s: float = 0.0
    config_files: tuple[str, ...] = ()
    gains_file: str = ""
    description: str = ""
    flush_interval_s: float = FLUSH_INTERVAL_S
    flush_messages: int = FLUSH_MESSAGES
    fsync: bool = False
    reserve_bytes: int = RESERVE_BYTES

    def __post_init__(self):
        if not self.out_dir:
            raise ConfigError("recorder: out_dir must not be empty")
        if not self.topics:
            raise ConfigError("recorder: topics must list at least one topic")
        for topic, msgtype in self.topics.items():
            if not isinstance(topic, str) or not topic.startswith("/"):
                raise ConfigError(f"recorder: topic {topic!r} must be an absolute name")
            if not isinstance(msgtype, str) or msgtype.count("/") != 2:
                raise ConfigError(
                    f"recorder: topics[{topic!r}] type {msgtype!r} is not 'pkg/msg/Name'"
                )
        if self.storage not in ("mcap", "sqlite3"):
            raise ConfigError(
                f"recorder: storage must be 'mcap' or 'sqlite3', got {self.storage!r}"
            )
        if self.split_size_bytes < 0:
            raise ConfigError("recorder: split_size_bytes must be >= 0")
        if self.split_duration_s < 0:
            raise ConfigError("recorder: split_duration_s must be >= 0")
        f = self.flush_interval_s
        if (
            isinstance(f, bool)
            or not isinstance(f, (int, float))
            or not math.isfinite(f)
            or not 0 < f <= 1.0
        ):
            raise ConfigError(
                f"recorder: flush_interval_s must be in (0, 1] s (the data a "
                f"killed recorder may lose), got {f!r}"
            )
        for name, lo in (("flush_messages", 1), ("reserve_bytes", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ConfigError(f"recorder: {name} must be an integer >= {lo}, got {v!r}")
        if not isinstance(self.fsync, bool):
            raise ConfigError(f"recorder: fsync must be true or false, got {self.fsync!r}")

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
