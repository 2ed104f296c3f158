"""Damaged sqlite3 storage files: reading what is readable, rolling back an unfinished
transaction and the repair of a ``.db3`` file.

rosbags reads sqlite3 bags with ``immutable=1``, which ignores a hot journal (a writer
killed inside a commit) and could see half a commit, and refuses a truncated file; this
module lets SQLite roll the journal back (in a copy when only reading) and reads the rows
before the first missing page. Every file is checked to be a regular file before sqlite3
opens it by name (:mod:`lpv_sysid.io.bag.bagfiles`).
"""

from __future__ import annotations

import contextlib
import sqlite3
import struct
import tempfile
from pathlib import Path
from typing import Iterator

from lpv_sysid.errors import BagError
from lpv_sysid.io.bag.bagfiles import check_file, copy_file, hot_journal, journal_of, read_file
from lpv_sysid.io.bag.records import TopicStats, _add_stats, _FileInfo, _Source


def _salvage_sqlite(path: Path, topics: set | None, src: _Source, problems: list) -> None:
    """Readable rows of a damaged sqlite3 file. A truncated file is first padded (in a
    temporary copy) with zero pages up to the size its header declares: SQLite refuses a
    file shorter than that, while the pages before the cut are intact, so rows are read in
    id order until the first missing page."""
    raw = read_file(path, path.parent)
    if raw[:16] == b"SQLite format 3\x00" and len(raw) >= 32:
        (page,) = struct.unpack(">H", raw[16:18])
        page = 65536 if page == 1 else page
        (npages,) = struct.unpack(">I", raw[28:32])
        if len(raw) < page * npages:
            problems.append(f"{path}: truncated: {len(raw)} of {page * npages} bytes present")
            # Drop the partial last page; fill the missing pages with 0xFF so that any
            # access to them (b-tree page type 0xFF, overflow pointer 0xFFFFFFFF beyond
            # the file) is reported as corruption instead of reading zeros as data.
            keep = raw[: len(raw) // page * page]
            with tempfile.TemporaryDirectory() as tmp:
                padded = Path(tmp) / path.name
                padded.write_bytes(keep + b"\xff" * (page * npages - len(keep)))
                _read_sqlite_rows(padded, path, topics, src, problems)
            return
    _read_sqlite_rows(path, path, topics, src, problems)


def _read_sqlite_rows(
    path: Path, name: Path, topics: set | None, src: _Source, problems: list
) -> None:
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True)
    except sqlite3.Error as exc:
        problems.append(f"{name}: cannot open sqlite3 file: {exc}")
        return
    try:
        try:
            for msgtype, enc, text in con.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
            ):
                if enc == "ros2msg":
                    src.msgdefs.setdefault(msgtype, text)
        except sqlite3.Error as exc:
            problems.append(f"{name}: message definitions unreadable: {exc}")
        try:
            tid = {i: (nm, typ) for i, nm, typ in con.execute("SELECT id, name, type FROM topics")}
        except sqlite3.Error as exc:
            problems.append(f"{name}: topics table unreadable: {exc}")
            return
        for topic_name, typ in tid.values():
            src.types[topic_name] = typ
        cur = con.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id")
        try:
            for t, ns, data in cur:
                topic = tid.get(t, (None,))[0]
                if topic is not None and (topics is None or topic in topics):
                    src.records.append((topic, ns, bytes(data)))
        except sqlite3.Error as exc:
            problems.append(f"{name}: messages table damaged after {len(src.records)} rows: {exc}")
    except sqlite3.Error as exc:
        problems.append(f"{name}: {exc}")
    finally:
        con.close()


@contextlib.contextmanager
def _settled(f: Path, problems: list) -> Iterator[Path]:
    """``f``, or for a sqlite3 file with a hot journal (writer killed inside a commit) a
    temporary copy in which SQLite rolled the unfinished transaction back: rosbags reads
    with ``immutable=1``, which ignores the journal and could see half a commit."""
    if f.suffix != ".db3" or not hot_journal(f, f.parent):
        yield f
        return
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / f.name
        copy_file(f, copy, f.parent)
        copy_file(journal_of(f), Path(tmp) / journal_of(f).name, f.parent)
        try:
            con = sqlite3.connect(str(copy))
            try:
                con.execute("SELECT count(*) FROM sqlite_master").fetchone()
            finally:
                con.close()
            problems.append(f"{f}: uncommitted transaction (hot journal) rolled back in a copy")
        except sqlite3.Error as exc:
            problems.append(f"{f}: hot journal could not be rolled back: {exc}")
        yield copy


def _repair_sqlite_file(f: Path, dry_run: bool) -> _FileInfo:
    from rosbags.rosbag2.metadata import parse_qos

    check_file(f, f.parent)
    hot = hot_journal(f, f.parent)
    notes = []
    with tempfile.TemporaryDirectory() as tmp:
        work = f
        if dry_run and hot:  # roll back in a copy, never in the original
            work = Path(tmp) / f.name
            copy_file(f, work, f.parent)
            copy_file(journal_of(f), Path(tmp) / journal_of(f).name, f.parent)
        try:
            con = sqlite3.connect(str(work))  # read-write: SQLite rolls a hot journal back
        except sqlite3.Error as exc:
            raise BagError(f"bag {f.parent}: {f.name}: cannot open: {exc}") from None
        try:
            (check,) = con.execute("PRAGMA quick_check").fetchone()
            if check != "ok":
                raise BagError(
                    f"bag {f.parent}: {f.name} is damaged ({check}); not repairable "
                    "in place -- read_bag(path, strict=False) recovers the "
                    "readable rows"
                )
            cols = {r[1] for r in con.execute("PRAGMA table_info(topics)")}
            qos_col = "offered_qos_profiles" if "offered_qos_profiles" in cols else "''"
            hash_col = "type_description_hash" if "type_description_hash" in cols else "''"
            rows = con.execute(
                f"SELECT id, name, type, serialization_format, {qos_col}, "
                f"{hash_col} FROM topics ORDER BY id"
            ).fetchall()
            stats = {
                tid: (n, lo, hi, nb)
                for tid, n, lo, hi, nb in con.execute(
                    "SELECT topic_id, count(*), min(timestamp), max(timestamp), "
                    "coalesce(sum(length(data)), 0) FROM messages GROUP BY topic_id"
                )
            }
        except sqlite3.Error as exc:
            raise BagError(
                f"bag {f.parent}: {f.name} is damaged ({exc}); not repairable in "
                "place -- read_bag(path, strict=False) recovers the readable "
                "rows"
            ) from None
        finally:
            con.close()
        rolled = hot and not journal_of(work).exists()
    if rolled:
        notes.append(
            f"{f.name}: uncommitted transaction rolled back" + (" (in a copy)" if dry_run else "")
        )
    conns: list[tuple] = []
    topics: dict[str, TopicStats] = {}
    nbytes = 0
    for tid, name, typ, fmt, qos, digest in rows:
        n, lo, hi, nb = stats.get(tid, (0, None, None, 0))
        nbytes += nb
        try:
            profiles = parse_qos(qos) if qos else []
        except Exception:  # noqa: BLE001
            profiles = []
        conns.append((name, typ, fmt, profiles, digest or "", n))
        topics[name] = _add_stats(topics.get(name), TopicStats(typ, n, lo, hi))
    return _FileInfo(f.name, conns, topics, nbytes, rolled, 0, notes)
