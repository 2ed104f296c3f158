"""What a data-logger :class:`~lpv_sysid.io.recorder.Recorder` records and how it splits
and flushes its bags: :class:`RecorderConfig`, validated."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from lpv_sysid.configuration import fields as cf
from lpv_sysid.io.bag import FLUSH_INTERVAL_S, FLUSH_MESSAGES, RESERVE_BYTES


@dataclass(frozen=True)
class RecorderConfig:
    """What to record and how to split it, checked on every construction.

    ``topics`` maps a topic name to its type ``pkg/msg/Name``. ``split_size_bytes`` /
    ``split_duration_s``: start a new bag directory when the current one holds this many
    payload bytes / this much recorded time (0 disables). ``config_files`` are copied
    verbatim into the metadata; ``gains_file`` is hashed (sha256). Durability
    (:class:`~lpv_sysid.io.bag.BagWriter`): ``flush_interval_s`` (0 < s <= 1) and
    ``flush_messages`` bound what a killed process loses, ``fsync`` makes each flush
    survive a power cut, ``reserve_bytes`` are kept free per bag for closing on a full disk.
    """

    out_dir: str = cf.text(doc="directory of the bags")
    topics: Mapping[str, str] = cf.table(
        doc="absolute topic name -> type pkg/msg/Name", item=cf.FieldSpec(cf.TEXT)
    )
    storage: str = cf.choice("mcap", ("mcap", "sqlite3"), "rosbag2 storage")
    split_size_bytes: int = cf.count(0, "new bag above this many payload bytes (0: never)")
    split_duration_s: float = cf.number(
        0.0, "new bag after this much recorded time [s] (0: never)", lo=0.0, unit=" s"
    )
    config_files: tuple[str, ...] = cf.texts(
        (), "files copied verbatim into the metadata", nonempty=False
    )
    gains_file: str = cf.text("", "gains file hashed into the metadata", nonempty=False)
    description: str = cf.text("", "free text of the metadata", nonempty=False)
    flush_interval_s: float = cf.number(
        FLUSH_INTERVAL_S,
        "flush at least this often [s]; (0, 1] s: the data a killed recorder may lose",
        lo=0.0,
        lo_open=True,
        hi=1.0,
        unit=" s",
    )
    flush_messages: int = cf.count(FLUSH_MESSAGES, "flush after this many messages", lo=1)
    fsync: bool = cf.flag(False, "fsync each flush (survives a power cut)")
    reserve_bytes: int = cf.count(
        RESERVE_BYTES,
        "disk space kept free per bag for closing on a full disk; at most 1 GiB",
        hi=1 << 30,
    )

    def __post_init__(self):
        """The declared fields, then: at least one topic, absolute names, pkg/msg/Name."""
        cf.normalize_fields(self, "recorder")
        if not self.topics:
            raise cf.error("recorder", "topics", "must list at least one topic")
        for topic, msgtype in self.topics.items():
            if not topic.startswith("/"):
                raise cf.error("recorder", "topics", f"topic {topic!r} must be an absolute name")
            if msgtype.count("/") != 2:
                raise cf.error(
                    "recorder", f"topics.{topic}", f"type {msgtype!r} is not 'pkg/msg/Name'"
                )

    @classmethod
    def from_dict(cls, d: Mapping, where: str = "recorder") -> "RecorderConfig":
        return cls(**cf.parse_fields(cls, d, where))
