"""What the readers return and pass between them: per-topic statistics, message lists,
column-wise arrays, raw records of a storage file and what a repair found in one."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable, Iterator, Mapping

import numpy as np


@dataclass(frozen=True)
class TopicStats:
    """Per-topic summary of a bag; ``rate_hz = (count - 1) / duration``."""

    msgtype: str
    count: int
    start_ns: int | None
    end_ns: int | None

    @property
    def duration_s(self) -> float:
        if self.start_ns is None or self.end_ns is None:
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


def _add_stats(old: TopicStats | None, new: TopicStats) -> TopicStats:
    """``new`` plus the messages of ``old`` (a second connection of the same topic): counts
    added, span widened, the type of ``new``."""
    if old is None:
        return new
    both = merge_topic_stats([{"t": old}, {"t": new}])["t"]
    return TopicStats(new.msgtype, both.count, both.start_ns, both.end_ns)


class BagContents(dict):
    """``{topic: [(stamp_ns, msg), ...]}`` plus ``types`` (topic -> msgtype) and
    ``problems`` (what could not be read; empty for a healthy bag)."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.types: dict[str, str] = {}
        self.problems: list[str] = []


class _Source:
    """Raw records of one storage: topic types, definitions and ``(topic, ns, bytes)``."""

    def __init__(self) -> None:
        self.types: dict[str, str] = {}
        self.msgdefs: dict[str, str] = {}  # msgtype -> ros2msg definition text
        self.records: list[tuple[str, int, Any]] = []  # data: bytes or a memoryview


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

    def __init__(self, *args: Any, **kw: Any) -> None:
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

    def groups(self) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """(times, order, block) per record length, the odd records folded in."""
        by_len: dict[int, list] = {}
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


@dataclass
class _FileInfo:
    """What one storage file holds (after a repair, or as found): its connections, the
    messages per topic and their payload bytes; ``changed`` / ``cut`` / ``notes``: what the
    repair did to it."""

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
