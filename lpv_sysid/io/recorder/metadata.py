"""What a :class:`~lpv_sysid.io.recorder.Recorder` has recorded and ``experiment.yaml``,
the metadata that reports it: per-topic (:class:`TopicStats`) and per-bag (:class:`BagInfo`)
counts, the static part (config files, gains sha256, git revision) and the atomic rewrite
of the file, whose counts are what is on disk (committed), never more (the durability rules:
:mod:`lpv_sysid.io.recorder`)."""

from __future__ import annotations

import logging
import os
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.bag import RepairReport
from lpv_sysid.io.files import sha256_file

if TYPE_CHECKING:
    from lpv_sysid.io.recorder.config import RecorderConfig

LOG = logging.getLogger(__name__)


@dataclass
class TopicStats:
    msgtype: str
    count: int = 0
    dropped: int = 0
    first_ns: int | None = None
    last_ns: int | None = None

    @property
    def rate_hz(self) -> float:
        if self.count < 2 or self.first_ns is None or self.last_ns is None:
            return 0.0
        if self.last_ns == self.first_ns:
            return 0.0
        return (self.count - 1) / ((self.last_ns - self.first_ns) * 1e-9)


@dataclass
class BagInfo:
    """One bag: what was recorded into it (``messages``, ``bytes``, stamps, ``topics``) and
    ``durable``, what is known to be on disk (last flush; the file's content after close)."""

    path: str
    start_ns: int | None = None
    end_ns: int | None = None
    messages: int = 0
    bytes: int = 0
    topics: dict = field(default_factory=dict)
    durable: dict | None = None

    def entry(self) -> dict:
        d = self.durable or {"topics": {}, "bytes": 0, "start_ns": None, "end_ns": None}
        return {
            "path": self.path,
            "messages": sum(d["topics"].values()),
            "bytes": d["bytes"],
            "start_ns": d["start_ns"],
            "end_ns": d["end_ns"],
        }


def git_revision(path: str | os.PathLike) -> str | None:
    """``git rev-parse HEAD`` of the repository containing ``path`` (None when unavailable)."""
    try:
        out = subprocess.run(
            ["git", "-C", str(path), "rev-parse", "HEAD"],
            check=True,
            capture_output=True,
            text=True,
            timeout=5,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def settle(bag: BagInfo, writer) -> None:
    """``bag.durable`` after its writer closed (cleanly or after an error)."""
    counts = getattr(writer, "durable_counts", None)
    topics = dict(bag.topics) if counts is None else dict(counts)
    n = sum(topics.values())
    rep = getattr(writer, "repair", None)
    if n >= bag.messages:
        span = (bag.bytes, bag.start_ns, bag.end_ns)
    elif isinstance(rep, RepairReport):
        starts = [s.start_ns for s in rep.topics.values() if s.start_ns is not None]
        ends = [s.end_ns for s in rep.topics.values() if s.end_ns is not None]
        span = (rep.bytes, min(starts) if starts else None, max(ends) if ends else None)
    elif bag.durable is not None:
        span = (bag.durable["bytes"], bag.durable["start_ns"], bag.durable["end_ns"])
    else:
        span = (0, None, None)
    bag.durable = {"topics": topics, "bytes": span[0], "start_ns": span[1], "end_ns": span[2]}


def static_metadata(cfg: RecorderConfig) -> dict:
    """The part of the metadata fixed at start: description, config files
    (verbatim), gains sha256, git revision."""
    files = {}
    from lpv_sysid.io.files import read_text

    for path in cfg.config_files:  # regular UTF-8 files of at most the YAML cap
        files[_relative(path, cfg.out_dir)] = read_text(path, f"recorder: config file {path}")
    gains = None
    if cfg.gains_file:
        try:
            gains = {
                "path": _relative(cfg.gains_file, cfg.out_dir),
                "sha256": sha256_file(cfg.gains_file),
            }
        except OSError as exc:
            raise ConfigError(
                f"recorder: gains file {cfg.gains_file}: {exc.strerror or exc}"
            ) from None
    here = Path(__file__).resolve().parent
    return {
        "description": cfg.description,
        "config_files": files,
        "gains": gains,
        "git_revision": git_revision(here),
    }


def _relative(path: str | os.PathLike, out_dir: str | os.PathLike) -> str:
    """``path`` relative to the experiment directory (the record moves with it); as given
    when there is no relative path (another drive)."""
    try:
        return os.path.relpath(Path(path).resolve(), Path(out_dir).resolve())
    except ValueError:
        return str(path)
