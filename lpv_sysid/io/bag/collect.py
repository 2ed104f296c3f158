"""The raw records of any bag: through the index reader, rosbags' AnyReader or, for a
damaged bag with ``strict=False``, the salvage readers (:func:`_collect`).

A healthy bag goes through :mod:`lpv_sysid.io.bag.mcap.index` or rosbags' ``AnyReader``
(which also names the problem of a damaged bag). With ``strict=False`` the storage files
are read one by one (rosbags reads ``.mcap`` / ``.db3`` files without metadata), and if
that fails too, the complete records of a truncated mcap are recovered by the record walk
(:mod:`lpv_sysid.io.bag.mcap.walk`) and the readable rows of a damaged sqlite3 file by the
sqlite3 module (:mod:`lpv_sysid.io.bag.sqlite`). The files are screened first
(:func:`~lpv_sysid.io.bag.metadata.screen_bag`): a FIFO or device is never opened.
"""

from __future__ import annotations

import logging
from pathlib import Path

from lpv_sysid.errors import BagError
from lpv_sysid.io.bag.bagfiles import METADATA, UnsafeBagFile, storage_files
from lpv_sysid.io.bag.durability import _describe
from lpv_sysid.io.bag.mcap.index import _read_fast
from lpv_sysid.io.bag.mcap.walk import _salvage_mcap
from lpv_sysid.io.bag.metadata import screen_bag
from lpv_sysid.io.bag.records import _Source
from lpv_sysid.io.bag.sqlite import _salvage_sqlite, _settled
from lpv_sysid.io.bag.typestore import jazzy_typestore

LOG = logging.getLogger(__name__)


def _read_with_rosbags(target: Path, topics: set | None, src: _Source) -> None:
    """Raw records of a healthy bag (directory with metadata.yaml, or a .mcap/.db3 file):
    through the chunk reader of :func:`_read_fast` when it applies, else through AnyReader
    (which also produces the error for a damaged bag)."""
    try:
        _read_fast(target, topics, src)
        return
    except UnsafeBagFile:
        raise
    except Exception as exc:  # noqa: BLE001 - AnyReader reads it (or names the problem)
        LOG.debug("bag %s: chunk reader not used (%s)", target, _describe(exc))
        src.types.clear()
        src.msgdefs.clear()
        src.records.clear()
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


def _read_file_tolerant(f: Path, topics: set | None, problems: list) -> _Source:
    with _settled(f, problems) as g:
        src = _Source()
        try:
            _read_with_rosbags(g, topics, src)
            return src
        except Exception as exc:  # noqa: BLE001 - rosbags raises many kinds
            problems.append(f"{f}: {_describe(exc)}")
        src = _Source()
        (_salvage_mcap if f.suffix == ".mcap" else _salvage_sqlite)(g, topics, src, problems)
        return src


def _collect(path, topics, strict: bool) -> tuple[list[_Source], list[str]]:
    path = Path(path)
    want = None if topics is None else set(topics)
    if not path.exists():
        raise BagError(f"bag {path}: does not exist")
    problems: list[str] = []
    bad = screen_bag(path, strict, problems)  # FIFOs, devices: never opened
    if path.is_dir():
        meta = path / METADATA
        if bad:
            why = f"bag {path}: files that are not regular files are left out"
        elif meta.exists():
            src = _Source()
            try:
                _read_with_rosbags(path, want, src)
                return [src], problems
            except Exception as exc:  # noqa: BLE001
                why = f"bag {path}: cannot be read ({_describe(exc)}); truncated or corrupt?"
        else:
            why = f"bag {path}: missing metadata.yaml (recording not closed?)"
        if strict:
            raise BagError(
                why + f" -- `lpv-sysid bag repair {path}` makes it readable by standard "
                "tools; read_bag(path, strict=False) recovers what is readable"
            )
        problems.append(why)
        files = [f for f in storage_files(path) if f not in bad]
        if not files:
            problems.append(f"bag {path}: no .mcap or .db3 storage file")
        return [_read_file_tolerant(f, want, problems) for f in files], problems
    if path.suffix not in (".mcap", ".db3"):
        raise BagError(f"bag {path}: not a bag directory, .mcap or .db3 file")
    if bad:
        return [], problems
    if strict:
        src = _Source()
        try:
            with _settled(path, problems) as g:
                _read_with_rosbags(g, want, src)
        except Exception as exc:  # noqa: BLE001
            raise BagError(
                f"bag {path}: cannot be read ({_describe(exc)}); truncated or "
                "corrupt? -- read_bag(path, strict=False) recovers what is readable"
            ) from None
        return [src], problems
    return [_read_file_tolerant(path, want, problems)], problems
