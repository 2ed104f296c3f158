"""Repair of a killed or starved recording: :func:`repair_bag` (``lpv-sysid bag repair DIR``).

In the spirit of ``ros2 bag reindex``, it makes the bag readable by standard tools: an
mcap file is cut after its last complete record and indexed in place
(:mod:`lpv_sysid.io.bag.mcap.repair`), a sqlite3 file has its uncommitted transaction
rolled back (:mod:`lpv_sysid.io.bag.sqlite`); then ``metadata.yaml`` is written from what
the storage files really hold (:mod:`lpv_sysid.io.bag.metadata`) and rosbags' AnyReader
checks the result. A bag locked by a live writer, or with a file that is not a regular
file (FIFO, device), is refused.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

from lpv_sysid.errors import BagError
from lpv_sysid.io.bag.bagfiles import check_file, storage_files
from lpv_sysid.io.bag.durability import LOCK_FILE, _describe, now_iso, writer_alive
from lpv_sysid.io.bag.mcap.repair import _repair_mcap_file
from lpv_sysid.io.bag.metadata import _metadata_matches, _write_bag_metadata, screen_bag
from lpv_sysid.io.bag.records import TopicStats, _FileInfo, merge_topic_stats
from lpv_sysid.io.bag.sqlite import _repair_sqlite_file
from lpv_sysid.io.bag.typestore import jazzy_typestore

LOG = logging.getLogger(__name__)


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


def repair_bag(
    path,
    dry_run: bool = False,
    *,
    _limit: int | None = None,
    _pending: tuple[bytes, int, int] | None = None,
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


def _repair_bag(
    path: Path, dry_run: bool, _limit: int | None, _pending: tuple[bytes, int, int] | None
) -> RepairReport:
    if not path.is_dir():
        raise BagError(f"bag {path}: not a bag directory")
    if os.path.lexists(path / LOCK_FILE):
        check_file(path / LOCK_FILE, path)  # a FIFO there is no lock of ours
    if writer_alive(path / LOCK_FILE):
        raise BagError(
            f"bag {path}: being written by a running process ({LOCK_FILE} is "
            "locked); stop the recorder first"
        )
    screen_bag(path)  # no FIFO or device in place of a file: refused, never opened
    files = storage_files(path)
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
    infos: list[_FileInfo] = []
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
        note = f"{now_iso()}: repaired by lpv_sysid ({action})"
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


def _check_readable(path: Path, infos: list[_FileInfo]) -> None:
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
