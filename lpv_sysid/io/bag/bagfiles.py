"""The files of a bag directory and the only way they are opened.

A bag path comes from the user, so every file of it (``metadata.yaml``, the ``.mcap`` /
``.db3`` storage files and a sqlite3 ``-journal``) is opened through
:func:`lpv_sysid.io.files.opening.open_regular`, or checked with
:func:`~lpv_sysid.io.files.opening.check_regular` just before rosbags or sqlite3 open it by
name: a FIFO, socket or device in its place (also behind a symlink) is refused before it
is opened, so it cannot block a reader or a repair, and the refusal is an
:class:`UnsafeBagFile` (a :class:`~lpv_sysid.errors.BagError`) naming the file. (Between
the check and a library's own ``open`` a file could still be swapped; the package's own
opens have no such window: ``open_regular`` checks the opened descriptor again.)
"""

from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path
from typing import BinaryIO, Iterator

from lpv_sysid.errors import BagError, ConfigError, FileReadError
from lpv_sysid.io.files import MAX_YAML_BYTES, check_regular, decode_text, open_regular

STORAGE_SUFFIXES = (".mcap", ".db3")
METADATA = "metadata.yaml"


class UnsafeBagFile(BagError):
    """A file of a bag is not a regular file (FIFO, socket, device, directory) or cannot be
    opened at all; never a reason to try another reader."""


def _refuse(exc: FileReadError, bag) -> BagError:
    """A missing file is an ordinary BagError (another reader may say more about the bag);
    one that exists but cannot be opened safely is an :class:`UnsafeBagFile`."""
    if not os.path.lexists(exc.path):
        return BagError(f"bag {bag}: {exc}")
    return UnsafeBagFile(f"bag {bag}: {exc}")


def check_file(path, bag) -> None:
    """Raise :class:`UnsafeBagFile` unless ``path`` is a regular file (symlinks followed;
    a missing file or dangling link: :class:`~lpv_sysid.errors.BagError`)."""
    try:
        check_regular(path)
    except FileReadError as exc:
        raise _refuse(exc, bag) from None


@contextlib.contextmanager
def open_file(path, bag, *, writable: bool = False) -> Iterator[BinaryIO]:
    """``path`` opened for binary reading (``writable``: read-write), any size."""
    with contextlib.ExitStack() as stack:
        try:
            fh = stack.enter_context(open_regular(path, max_bytes=None, writable=writable))
        except FileReadError as exc:
            raise _refuse(exc, bag) from None
        yield fh


def read_file(path, bag, max_bytes: int | None = None) -> bytes:
    """All bytes of the regular file ``path`` (``max_bytes``: refuse a larger file)."""
    try:
        with open_regular(path, max_bytes=max_bytes) as fh:
            return fh.read()
    except FileReadError as exc:
        raise _refuse(exc, bag) from None


def read_metadata_text(path, bag) -> str:
    """The text of a ``metadata.yaml`` (UTF-8, at most the YAML size cap)."""
    data = read_file(path, bag, MAX_YAML_BYTES)
    try:
        return decode_text(data, str(path))
    except ConfigError as exc:  # not UTF-8 text
        raise BagError(f"bag {bag}: {exc}") from None


def storage_files(directory: Path) -> list[Path]:
    """The ``.mcap`` / ``.db3`` entries of a bag directory, sorted (of any file type: see
    :func:`check_bag`)."""
    return sorted(p for p in directory.iterdir() if p.suffix in STORAGE_SUFFIXES)


def journal_of(f: Path) -> Path:
    return f.with_name(f.name + "-journal")


def hot_journal(f: Path, bag) -> bool:
    """Whether the sqlite3 file ``f`` has a non-empty journal (a regular file, else
    :class:`UnsafeBagFile`)."""
    journal = journal_of(f)
    if not os.path.lexists(journal):
        return False
    check_file(journal, bag)
    return journal.stat().st_size > 0


def copy_file(src: Path, dst: Path, bag) -> None:
    """Copy the regular file ``src`` to the new file ``dst`` (streamed)."""
    with open_file(src, bag) as fin, open(dst, "xb") as fout:
        shutil.copyfileobj(fin, fout, 1 << 20)
