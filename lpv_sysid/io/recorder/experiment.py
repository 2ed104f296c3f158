"""The experiment directory a :class:`~lpv_sysid.io.recorder.Recorder` writes, and its
repair after a kill (``lpv-sysid bag repair OUT``).

Layout::

    out/experiment.yaml        metadata (format :data:`METADATA_FORMAT`)
    out/bag_0000/              rosbag2 directories, numbered
    out/.lpv_sysid_recording   lock + disk reserve while a recorder runs (:data:`LOCK_FILE`)

:func:`repair_experiment` makes a directory whose recorder was killed (or starved)
readable by standard tools and its ``experiment.yaml`` truthful.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path

import yaml

from lpv_sysid.errors import BagError, FileReadError
from lpv_sysid.io.bag import (
    merge_topic_stats,
    now_iso,
    repair_bag,
    writer_alive,
)
from lpv_sysid.io.files import atomic_write_text, check_regular, read_yaml

LOG = logging.getLogger(__name__)
METADATA_FORMAT = "lpv_sysid/experiment@1"
METADATA_FILE = "experiment.yaml"
#: lock + metadata disk reserve of a running Recorder, in the experiment directory
LOCK_FILE = ".lpv_sysid_recording"
STATUSES = ("recording", "incomplete", "closed_cleanly")
_BAG_DIR = re.compile(r"bag_[0-9]{4}")


@dataclass(frozen=True)
class ExperimentRepair:
    """What :func:`repair_experiment` found and did: one
    :class:`~lpv_sysid.io.bag.RepairReport` per bag, the status before and after, and the
    bags that could not be repaired (``errors``)."""

    out_dir: str
    bags: tuple
    status_before: str
    status: str
    changed: bool
    errors: tuple = ()
    dry_run: bool = False

    @property
    def messages(self) -> int:
        return sum(r.messages for r in self.bags)

    def summary(self) -> str:
        head = f"{METADATA_FILE}: status {self.status_before}"
        if self.changed:
            head += (" -> " if not self.dry_run else " -> would be ") + self.status
        else:
            head += ", nothing to do"
        parts = [head, f"{self.messages} message(s) readable in {len(self.bags)} bag(s)"]
        return "; ".join(parts + list(self.errors))


def repair_experiment(out_dir, dry_run: bool = False) -> ExperimentRepair:
    """Make an experiment directory whose recorder was killed (or starved) readable by
    standard tools and its ``experiment.yaml`` truthful: :func:`~lpv_sysid.io.bag.repair_bag`
    on every bag, then the counts, spans and bags from what the bags hold, ``status:
    incomplete`` (kept ``closed_cleanly`` when nothing needed repair), the ``error`` (an
    interrupted recording says so) and a ``repaired`` record. Refuses a directory whose
    recorder is alive. ``dry_run`` changes nothing."""
    out = Path(out_dir)
    path = out / METADATA_FILE
    meta = read_yaml(path, finite=False)  # a package output: rates may be .nan
    if not isinstance(meta, dict) or meta.get("format") != METADATA_FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise BagError(
            f"recorder: {path}: not an lpv_sysid experiment file "
            f"(format {got!r}, expected {METADATA_FORMAT!r})"
        )
    if os.path.lexists(out / LOCK_FILE):  # a FIFO or device there is no lock of ours
        try:
            check_regular(out / LOCK_FILE)
        except FileReadError as exc:
            raise BagError(f"recorder: {exc}") from None
    if writer_alive(out / LOCK_FILE):
        raise BagError(
            f"recorder: {out} is being recorded by a running process "
            f"({LOCK_FILE} is locked); stop it first"
        )
    names: list[str] = []
    for b in meta.get("bags") or []:
        name = b.get("path") if isinstance(b, dict) else None
        if isinstance(name, str) and _BAG_DIR.fullmatch(name) and name not in names:
            names.append(name)
    for p in sorted(out.iterdir()):
        if p.is_dir() and _BAG_DIR.fullmatch(p.name) and p.name not in names:
            names.append(p.name)
    reports, errors = [], []
    for name in names:
        if not (out / name).is_dir():
            errors.append(f"{name}: missing")
            continue
        try:
            reports.append(repair_bag(out / name, dry_run))
        except BagError as exc:
            errors.append(f"{name}: not repaired: {exc}")
    before = meta.get("status")
    if before not in STATUSES:  # written before the status field existed
        before = (
            "closed_cleanly"
            if meta.get("closed_cleanly")
            else ("incomplete" if meta.get("error") else "recording")
        )
    interrupted = before == "recording"  # ... and its lock is gone: the recorder died
    changed = (
        interrupted
        or bool(errors)
        or any(r.changed for r in reports)
        or (out / LOCK_FILE).exists()
    )
    status = (
        "closed_cleanly"
        if before == "closed_cleanly" and not errors and not any(r.changed for r in reports)
        else "incomplete"
    )
    if not changed:
        return ExperimentRepair(str(out), tuple(reports), before, before, False, (), dry_run)
    new = dict(meta)
    new["status"] = status
    new["closed_cleanly"] = status == "closed_cleanly"
    if interrupted and not new.get("error"):
        new["error"] = (
            "recording interrupted: the recorder ended without closing (killed, "
            "crashed or lost power)"
        )
    raw_topics = meta.get("topics")
    old_topics: dict = raw_topics if isinstance(raw_topics, dict) else {}
    merged = merge_topic_stats(r.topics for r in reports)
    topics = {}
    for t in list(old_topics) + [t for t in merged if t not in old_topics]:
        entry = dict(old_topics.get(t) or {})
        got = merged.get(t)
        n = got.count if got is not None else 0
        entry["type"] = entry.get("type") or (got.msgtype if got is not None else None)
        entry["count"] = n
        entry.setdefault("dropped", 0)
        lo, hi = (got.start_ns, got.end_ns) if got is not None else (None, None)
        entry["rate_hz"] = (
            round((n - 1) / ((hi - lo) * 1e-9), 6)
            if n > 1 and lo is not None and hi is not None and hi > lo
            else 0.0
        )
        topics[t] = entry
    new["topics"] = topics
    new["bags"] = [
        {
            "path": Path(r.path).name,
            "messages": r.messages,
            "bytes": r.bytes,
            "start_ns": min(
                (s.start_ns for s in r.topics.values() if s.start_ns is not None), default=None
            ),
            "end_ns": max(
                (s.end_ns for s in r.topics.values() if s.end_ns is not None), default=None
            ),
        }
        for r in reports
    ]
    if new.get("stop_stamp_ns") is None:
        ends = [b["end_ns"] for b in new["bags"] if b["end_ns"] is not None]
        new["stop_stamp_ns"] = max(ends) if ends else None
    new["repaired"] = {
        "time": now_iso(),
        "by": "lpv_sysid.io.recorder.repair_experiment",
        "status_before": before,
        "bags": {Path(r.path).name: r.summary() for r in reports},
        "errors": errors or None,
    }
    result = ExperimentRepair(
        str(out), tuple(reports), before, status, True, tuple(errors), dry_run
    )
    if dry_run:
        return result
    try:
        atomic_write_text(path, yaml.safe_dump(new, sort_keys=False), fsync=True)
    except OSError as exc:
        raise BagError(f"recorder: cannot write {path}: {exc.strerror or exc}") from None
    with contextlib.suppress(FileNotFoundError):
        (out / LOCK_FILE).unlink()
    LOG.warning("%s: %s", out, result.summary())
    return result
