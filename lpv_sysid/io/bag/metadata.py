"""``metadata.yaml``, the bag's table of contents: read (for the index reader and to screen the
files it names before anything opens them), compared with what the storage files hold and
written after a repair (rosbag2 format version 9, as rosbags' Writer writes it; a healthy
bag's file is written by rosbags itself)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from lpv_sysid.errors import BagError
from lpv_sysid.io.bag.bagfiles import (
    METADATA,
    UnsafeBagFile,
    check_file,
    hot_journal,
    read_metadata_text,
    storage_files,
)
from lpv_sysid.io.bag.records import _FileInfo
from lpv_sysid.io.files import atomic_write_text


def _yaml_load(text: str) -> Any:
    """metadata.yaml / QoS text through the package's YAML loader (libyaml parser)."""
    from lpv_sysid.io.files import strict_load

    return strict_load(text)


def load_metadata(path: Path) -> dict:
    """The ``rosbag2_bagfile_information`` mapping of the bag directory ``path``.

    :class:`~lpv_sysid.io.bag.bagfiles.UnsafeBagFile` when the file is not a regular file;
    ``yaml.YAMLError``, ``KeyError`` or ``TypeError`` when it is not rosbag2 metadata."""
    info = _yaml_load(read_metadata_text(path / METADATA, path))["rosbag2_bagfile_information"]
    if not isinstance(info, dict):
        raise TypeError(f"rosbag2_bagfile_information is a {type(info).__name__}")
    return info


def _metadata_matches(path: Path, storage: str, infos: list[_FileInfo]) -> bool:
    """Whether the bag's metadata.yaml names exactly these files and message counts."""
    try:
        info = load_metadata(path)
        if info["storage_identifier"] != storage:
            return False
        if [Path(p).name for p in info["relative_file_paths"]] != [i.name for i in infos]:
            return False
        if info["message_count"] != sum(i.count for i in infos):
            return False
        have: dict[tuple[str, str], int] = {}
        for t in info["topics_with_message_count"]:
            key = (t["topic_metadata"]["name"], t["topic_metadata"]["type"])
            have[key] = have.get(key, 0) + t["message_count"]
    except (BagError, OSError, yaml.YAMLError, KeyError, TypeError):
        return False  # missing or unreadable: to be regenerated
    want: dict[tuple[str, str], int] = {}
    for i in infos:
        for topic, typ, _fmt, _qos, _digest, n in i.conns:
            want[(topic, typ)] = want.get((topic, typ), 0) + n
    return have == want


def _write_bag_metadata(path: Path, storage: str, infos: list[_FileInfo], note: str) -> None:
    """``metadata.yaml`` (rosbag2 format version 9, as rosbags' Writer writes it) from what
    the storage files hold."""
    from rosbags.rosbag2.metadata import dump_qos_v9

    merged: dict[tuple, dict[str, Any]] = {}
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
    atomic_write_text(path / METADATA, yaml.safe_dump(meta, sort_keys=False), fsync=True)


def screen_bag(path: Path, strict: bool = True, problems: list[str] | None = None) -> set[Path]:
    """The files of the bag ``path`` that must not be opened: its ``metadata.yaml``, the
    storage files in the directory and those its metadata lists, and sqlite3 journals,
    when they are not regular files. ``strict``: the first one raises
    :class:`UnsafeBagFile`; else each is described in ``problems`` and returned. What
    rosbags and sqlite3 open by name is screened here first."""
    cands: list[Path] = []
    if path.is_dir():
        meta = path / METADATA
        cands.append(meta)
        names: list[str] = []
        if meta.is_file():
            try:  # the files rosbags' reader opens (by name, inside the directory)
                names = [str(n) for n in load_metadata(path)["relative_file_paths"]]
            except Exception:  # noqa: BLE001 - unreadable metadata: the readers say why
                names = []
        cands += sorted(set(storage_files(path)) | {path / Path(n).name for n in names})
    else:
        cands.append(path)
    bad: set[Path] = set()
    for f in cands:
        if not os.path.lexists(f):
            continue
        try:
            check_file(f, path)
            if f.suffix == ".db3":
                hot_journal(f, path)
        except UnsafeBagFile as exc:
            if strict:
                raise
            if problems is not None:
                problems.append(str(exc))
            bad.add(f)
    return bad
