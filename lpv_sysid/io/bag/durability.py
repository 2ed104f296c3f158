"""What keeps a recording readable when its process dies: the writer's lock and disk
reserve and the "is a writer alive?" test (atomic text files:
:func:`lpv_sysid.io.files.atomic_write_text`).

While a :class:`~lpv_sysid.io.bag.writer.BagWriter` is open, the bag directory holds
:data:`LOCK_FILE`, a :class:`DiskReserve`: locked with ``flock`` (the kernel drops the lock
when the process dies, also on ``kill -9``, so a held lock means "a live writer", see
:func:`writer_alive`) and filled with ``reserve_bytes`` of disk space that is given back
first on a write error, so that the index and ``metadata.yaml`` can still be written on a
full disk.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import fcntl
import os
import stat
from pathlib import Path
from typing import BinaryIO

#: lock + disk reserve of an open :class:`BagWriter`, inside the bag directory
LOCK_FILE = ".lpv_sysid_writing"
RESERVE_BYTES = 1 << 20


def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.errno is not None:
        name = errno.errorcode.get(exc.errno, str(exc.errno))
        return f"{name}: {exc.strerror or os.strerror(exc.errno)}"
    return f"{type(exc).__name__}: {exc}"


class DiskReserve:
    """A file locked with ``flock`` that holds ``size`` bytes of disk space.

    The lock says "a live process owns this directory": the kernel drops it when the
    process ends, however it ends (also ``kill -9``), so a stale file is recognised by
    :func:`writer_alive`. The bytes are random (a compressing file system cannot shrink
    them) and are given back by :meth:`release` -- first thing on a write error -- so the
    owner can still finish its files on a full disk.
    """

    def __init__(self, path, size: int):
        self.path = Path(path)
        self.size = int(size)
        self._fh: BinaryIO | None = None

    def acquire(self) -> "DiskReserve":
        """Create, lock and fill the file; raises OSError (ENOSPC when there is no room)."""
        fh = open(self.path, "xb")
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            left = self.size
            while left > 0:
                n = min(left, 1 << 16)
                fh.write(os.urandom(n))
                left -= n
            fh.flush()
        except BaseException:
            fh.close()
            with contextlib.suppress(OSError):
                self.path.unlink()
            raise
        self._fh = fh
        return self

    @property
    def held(self) -> bool:
        return self._fh is not None

    def free_space(self) -> bool:
        """Give the space back but keep the lock; True if there was space to give."""
        if self._fh is None:
            return False
        try:
            if os.fstat(self._fh.fileno()).st_size == 0:
                return False
            self._fh.truncate(0)
            self._fh.flush()
        except OSError:
            return False
        return True

    def release(self) -> None:
        """Give the space back and drop the lock (idempotent, never raises)."""
        fh, self._fh = self._fh, None
        if fh is None:
            return
        with contextlib.suppress(OSError):
            self.path.unlink()
        with contextlib.suppress(OSError):
            fh.close()


def writer_alive(lock_path) -> bool:
    """True when a live process holds the :class:`DiskReserve` lock at ``lock_path``.

    Opened with ``O_NONBLOCK | O_NOFOLLOW``: a FIFO, device or symlink planted there never
    blocks or redirects the check (anything but a regular file counts as "alive", so no
    repair runs over it)."""
    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0) | os.O_CLOEXEC
    try:
        fd = os.open(lock_path, flags)
    except FileNotFoundError:
        return False
    except OSError:
        return True  # cannot tell: assume alive, never repair under a writer
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return True
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # BlockingIOError: a live process holds the lock
        return True
    finally:
        os.close(fd)  # closing drops our own lock, if we got it
    return False


def now_iso() -> str:
    """The current UTC time, ISO 8601 with milliseconds (metadata time stamps)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")
