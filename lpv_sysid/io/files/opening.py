"""The one place user-supplied files are opened for reading.

Every reader of a user file (YAML configs, model/gains files, ``.npz`` tables, signing keys)
goes through :func:`open_regular` (or :func:`read_bytes` / :func:`read_text` /
:func:`read_npz` built on it), so that every hostile file ends in one
:class:`~lpv_sysid.errors.ConfigError` naming the path and the problem, never a hang, a
``MemoryError`` or a traceback:

* the path is ``stat``-ed first and must be a **regular file** (after following symlinks):
  a directory, FIFO, socket or device is refused *before* it is opened, so a FIFO cannot
  block the reader and a serial port is not touched; the file is then opened with
  ``O_NONBLOCK`` and ``fstat``-ed again (no race with a swap in between);
* missing files, symlink loops and permission problems give the OS reason
  (``cannot read (Permission denied)``);
* a **size cap** (:data:`MAX_YAML_BYTES`, :data:`MAX_NPZ_BYTES`, per call for others) is
  checked on the size *and* while reading (files that grow, ``/proc``-like files), so
  ``/dev/zero`` or a 10 GB file never reach memory;
* text must be UTF-8 (a UTF-8 byte-order mark is accepted); UTF-16/32 text, NUL bytes and
  invalid UTF-8 are refused with the byte offset;
* ``.npz`` archives are read member by member with ``allow_pickle=False``: each ``.npy``
  header (shape, dtype) is checked before any array is allocated (no object arrays, no
  complex arrays unless asked for, at most :data:`MAX_NPZ_BYTES` of array data in total,
  so a compressed "zip bomb" is refused too); empty, truncated and corrupt archives
  (bad zip directory, CRC errors, short data) are one ConfigError.

Messages have the form ``"{label}: {problem}"`` where ``label`` defaults to the path; with
``show_path`` (for labels that are not the path, e.g. a bare file name) the path is added to
the reason an open fails: ``"gains.yaml: cannot read /data/gains.yaml (Permission denied)"``.
"""

from __future__ import annotations

import codecs
import contextlib
import os
import stat
import struct
import zipfile
import zlib
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO, Iterator, Optional

import numpy as np

from lpv_sysid.errors import ConfigError, FileReadError

MiB = 1 << 20
#: Largest YAML file read (configs, models, gains, summaries); real files are < 1 MiB.
MAX_YAML_BYTES = 64 * MiB
#: Largest ``.npz`` file read, and largest total of the array data it may hold.
MAX_NPZ_BYTES = 256 * MiB

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def _size(n: int) -> str:
    return f"{n / MiB:.0f} MiB" if n >= MiB else f"{n} bytes"


def _kind(mode: int) -> str:
    for test, name in _KINDS:
        if test(mode):
            return name
    return "not a regular file"


def _cannot(label: str, shown: str, reason: str, path) -> FileReadError:
    return FileReadError(f"{label}: cannot read {shown}({reason})", os.fspath(path), reason)


def _check_stat(
    st: os.stat_result, label: str, max_bytes: Optional[int], shown: str, path
) -> None:
    if stat.S_ISDIR(st.st_mode):
        raise _cannot(label, shown, "Is a directory", path)
    if not stat.S_ISREG(st.st_mode):
        raise _cannot(label, shown, f"not a regular file: {_kind(st.st_mode)}", path)
    if max_bytes is not None and st.st_size > max_bytes:
        reason = f"file too large ({_size(st.st_size)}; the limit is {_size(max_bytes)})"
        raise FileReadError(f"{label}: {shown}{reason}", os.fspath(path), reason)


def _oserror(exc: OSError, label: str, shown: str, path) -> FileReadError:
    return _cannot(label, shown, str(exc.strerror or exc), path)


def _shown(path, label: Optional[str], show_path: bool) -> tuple[str, str]:
    p = os.fspath(path)
    if label is None:
        return p, ""
    return label, (f"{p} " if show_path and p != label else "")


def check_regular(
    path, label: Optional[str] = None, max_bytes: Optional[int] = None, *, show_path: bool = False
) -> None:
    """Refuse (ConfigError ``"{label}: ..."``) ``path`` unless it is a regular file (after
    following symlinks) of at most ``max_bytes`` (None: any size): for files that a library
    opens by name (rosbags, sqlite3), checked just before it does."""
    p = os.fspath(path)
    label, shown = _shown(p, label, show_path)
    try:
        st = os.stat(p)
    except OSError as exc:
        raise _oserror(exc, label, shown, p) from None
    except (ValueError, UnicodeError) as exc:
        raise _cannot(label, shown, f"invalid path: {exc}", p) from None
    _check_stat(st, label, max_bytes, shown, p)


@contextmanager
def open_regular(
    path,
    label: Optional[str] = None,
    max_bytes: Optional[int] = MAX_YAML_BYTES,
    *,
    show_path: bool = False,
    writable: bool = False,
) -> Iterator[BinaryIO]:
    """Open ``path`` for binary reading if it is a regular file of at most ``max_bytes``
    (None: any size; e.g. a recording read in chunks).

    ``stat`` before ``open`` (non-regular files are never opened), ``O_NONBLOCK`` and
    ``fstat`` after it; every failure is a ConfigError ``"{label}: ..."``. ``writable``
    opens it read-write (``r+b``, e.g. an in-place repair) after the same checks.
    """
    p = os.fspath(path)
    label, shown = _shown(p, label, show_path)
    try:
        _check_stat(os.stat(p), label, max_bytes, shown, p)
        flags = (
            (os.O_RDWR if writable else os.O_RDONLY)
            | getattr(os, "O_NONBLOCK", 0)
            | getattr(os, "O_NOCTTY", 0)
            | getattr(os, "O_CLOEXEC", 0)
            | getattr(os, "O_BINARY", 0)
        )
        fd = os.open(p, flags)
    except OSError as exc:
        raise _oserror(exc, label, shown, p) from None
    except (ValueError, UnicodeError) as exc:  # embedded NUL or unencodable path
        raise _cannot(label, shown, f"invalid path: {exc}", p) from None
    try:
        _check_stat(os.fstat(fd), label, max_bytes, shown, p)
        fh = os.fdopen(fd, "r+b" if writable else "rb")
    except BaseException:
        os.close(fd)
        raise
    with fh:
        yield fh


def read_bytes(
    path, label: Optional[str] = None, max_bytes: int = MAX_YAML_BYTES, *, show_path: bool = False
) -> bytes:
    """All bytes of the regular file ``path`` (at most ``max_bytes``, else ConfigError)."""
    label, shown = _shown(path, label, show_path)
    chunks, total = [], 0
    with open_regular(path, label, max_bytes, show_path=show_path) as fh:
        # in chunks up to one byte past the cap: a file that grows (or /proc, size 0) is caught
        try:
            while total <= max_bytes:
                chunk = fh.read(min(1 << 20, max_bytes + 1 - total))
                if not chunk:
                    break
                chunks.append(chunk)
                total += len(chunk)
        except OSError as exc:
            raise _oserror(exc, label, shown, path) from None
    data = b"".join(chunks)
    if len(data) > max_bytes:
        reason = f"file too large (it grew past the limit of {_size(max_bytes)})"
        raise FileReadError(f"{label}: {shown}{reason}", os.fspath(path), reason)
    return data


_WIDE_BOMS = (
    (codecs.BOM_UTF32_LE, "UTF-32"),
    (codecs.BOM_UTF32_BE, "UTF-32"),
    (codecs.BOM_UTF16_LE, "UTF-16"),
    (codecs.BOM_UTF16_BE, "UTF-16"),
)


def decode_text(data: bytes, label: str) -> str:
    """UTF-8 text of ``data`` (optional UTF-8 BOM dropped); UTF-16/32, NUL bytes and invalid
    UTF-8 are ConfigErrors naming the encoding or the byte offset."""
    for bom, name in _WIDE_BOMS:  # UTF-32-LE starts with the UTF-16-LE BOM: order matters
        if data.startswith(bom):
            raise ConfigError(
                f"{label}: not UTF-8 text ({name} byte-order mark); save the file as UTF-8"
            )
    nul = data.find(b"\x00")
    if nul >= 0:
        hint = "UTF-16/32 text without a byte-order mark, or a binary file"
        raise ConfigError(f"{label}: not UTF-8 text (NUL byte at byte {nul}: {hint})")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{label}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def read_text(
    path, label: Optional[str] = None, max_bytes: int = MAX_YAML_BYTES, *, show_path: bool = False
) -> str:
    """UTF-8 text of the regular file ``path`` (:func:`read_bytes` + :func:`decode_text`)."""
    label, shown = _shown(path, label, show_path)
    data = read_bytes(path, label, max_bytes, show_path=show_path)
    return decode_text(data, f"{label}: {shown.strip()}" if shown else label)


def check_output(path, label: Optional[str] = None) -> None:
    """Refuse to write ``path`` when it exists and is not a regular file (an ``open(path, "w")``
    of a FIFO blocks until a reader appears; a device or directory is never an output)."""
    p = os.fspath(path)
    label = p if label is None else label
    try:
        st = os.stat(p)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise FileReadError(
            f"{label}: cannot write ({exc.strerror or exc})", p, str(exc.strerror or exc)
        ) from None
    if not stat.S_ISREG(st.st_mode):
        reason = f"not a regular file: {_kind(st.st_mode)}"
        raise FileReadError(f"{label}: cannot write ({reason})", p, reason)


def _same(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return os.path.realpath(a) == os.path.realpath(b)


def read_key(path, what: str) -> bytes:
    """A 32-byte secret from a key file (an operator seal key, a MAVLink 2 signing key): 32
    raw bytes, or 64 hexadecimal characters; regular files only (a FIFO would block), at most
    4 KiB. ConfigError ``"{what} {path!r}: ..."`` otherwise."""
    import binascii

    try:
        raw = read_bytes(path, f"{what} {path!r}", max_bytes=4096)
    except FileReadError as exc:
        raise ConfigError(f"{what} {path!r} cannot be read: {exc.reason}") from None
    if len(raw) == 32:
        return raw
    text = raw.strip()
    if len(text) == 64:
        try:
            return binascii.unhexlify(text)
        except (binascii.Error, ValueError):
            raise ConfigError(f"{what} {path!r}: 64 characters but not hexadecimal") from None
    raise ConfigError(
        f"{what} {path!r}: expected 32 raw bytes or 64 hex characters, got {len(raw)} bytes"
    )


def refuse_overwrite(
    out,
    inputs: "list[tuple[str, str]]",
    force: bool = False,
    flag: str = "--out",
    force_hint: str = "force the replacement",
) -> None:
    """The one check of an output against the inputs of the same run: ConfigError when
    ``out`` is (the same file as) one of ``inputs`` (``(name, path)`` pairs, e.g.
    ``("--gains", "g.yaml")``) -- ``verify --out gains.yaml`` would replace the gains,
    ``synthesize --models M --out M`` the models -- unless ``force``; ``force_hint``: how
    the caller forces it (the CLI: its flag)."""
    if force or out is None:
        return
    o = os.fspath(out)
    if not os.path.lexists(o):
        return
    for name, path in inputs:
        if path and os.path.lexists(path) and _same(o, path):
            raise ConfigError(
                f"{flag} {o} is the input {name} {path}: refusing to overwrite an input "
                f"(choose another output, or {force_hint})"
            )


def refuse_existing(paths, force: bool = False, why: str = "") -> None:
    """ConfigError naming the ``paths`` that exist already, unless ``force`` (an output that
    would silently replace files something else refers to, e.g. the signal set a
    certificate's design envelope was computed from)."""
    paths = [os.fspath(p) for p in paths]
    for p in paths:
        check_output(p)  # a FIFO, device or directory is never an output, --force or not
    if force:
        return
    there = [p for p in paths if os.path.lexists(p)]
    if there:
        raise ConfigError(
            f"{', '.join(there)} exist(s) already{why}: refusing to replace them (another "
            "output directory, or force the replacement)"
        )


# ----------------------------------------------------------------------------- npz
_ZIP_ERRORS = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    zlib.error,
    EOFError,
    ValueError,
    OSError,
    struct.error,
    NotImplementedError,  # zipfile: an unsupported compression method in the archive
    RuntimeError,
    KeyError,
    OverflowError,
)


def _npy_header(fp) -> tuple[tuple, np.dtype]:
    version = np.lib.format.read_magic(fp)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(fp)
    elif version == (2, 0):
        shape, _, dtype = np.lib.format.read_array_header_2_0(fp)
    else:  # (3, 0): utf-8 field names; read_array handles it, the header check needs the
        # private reader (not in numpy's type stubs, hence getattr)
        private_reader = getattr(np.lib.format, "_read_array_header")
        shape, _, dtype = private_reader(fp, version)
    return shape, dtype


def read_npz(
    path,
    label: Optional[str] = None,
    max_bytes: int = MAX_NPZ_BYTES,
    *,
    allow_complex: bool = False,
    show_path: bool = False,
) -> dict[str, np.ndarray]:
    """The arrays of the ``.npz`` archive ``path`` as a dict (member name without ``.npy``).

    Refused with a ConfigError naming the file: anything :func:`open_regular` refuses, an
    empty file, a file that is not a zip archive (e.g. a bare ``.npy``), truncated or
    corrupt archives, members that are not ``.npy`` arrays, object (pickle) arrays,
    complex arrays (unless ``allow_complex``), and more than ``max_bytes`` of array data
    in total (checked from the headers before anything is allocated).
    """
    label, shown = _shown(path, label, show_path)
    out: dict[str, np.ndarray] = {}
    with open_regular(path, label, max_bytes, show_path=show_path) as fh:
        label = f"{label}: {shown.strip()}" if shown else label
        try:
            size = os.fstat(fh.fileno()).st_size
            if size == 0:
                raise ConfigError(f"{label}: not a readable .npz archive (empty file)")
            head = fh.read(6)
            fh.seek(0)
            if head == b"\x93NUMPY":
                raise ConfigError(
                    f"{label}: not a readable .npz archive (a single-array .npy file)"
                )
            total = 0
            with zipfile.ZipFile(fh) as zf:
                for info in zf.infolist():
                    name = info.filename
                    if not name.endswith(".npy"):
                        raise ConfigError(
                            f"{label}: not a readable .npz archive (member {name!r} is not a "
                            ".npy array)"
                        )
                    key = name[:-4]
                    if key in out:
                        raise ConfigError(
                            f"{label}: not a readable .npz archive (member {name!r} appears twice)"
                        )
                    with zf.open(info) as m:
                        shape, dtype = _npy_header(m)
                    if dtype.hasobject:
                        raise ConfigError(
                            f"{label}: array {key!r} holds Python objects (dtype {dtype}); "
                            "only numeric and string arrays are read (no pickles)"
                        )
                    if dtype.kind == "c" and not allow_complex:
                        raise ConfigError(
                            f"{label}: array {key!r} is complex-valued (dtype {dtype}); "
                            "a real-valued array is required"
                        )
                    count = 1
                    for s in shape:
                        count *= int(s)
                    total += count * dtype.itemsize
                    if total > max_bytes:
                        raise ConfigError(
                            f"{label}: arrays too large (array {key!r} of shape {tuple(shape)}, "
                            f"{dtype}: more than {_size(max_bytes)} of array data in total; "
                            f"the limit is {_size(max_bytes)})"
                        )
                    with zf.open(info) as m:
                        out[key] = np.lib.format.read_array(m, allow_pickle=False)
        except ConfigError:
            raise
        except MemoryError:
            raise ConfigError(f"{label}: arrays too large to load (out of memory)") from None
        except _ZIP_ERRORS as exc:
            reason = str(exc) or type(exc).__name__
            if isinstance(exc, zipfile.BadZipFile) and "not a zip file" in reason.lower():
                reason = "not a zip archive; truncated or not an .npz file"
            raise ConfigError(f"{label}: not a readable .npz archive ({reason})") from None
    return out


def atomic_write_text(path, text: str, fsync: bool = False) -> None:
    """Write ``text`` to ``path`` through ``path.tmp`` + rename: readers see the old or the
    new file, never half of one, and a failed write (disk full) leaves no ``.tmp`` behind.
    Raises OSError."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    # the .tmp name is ours: a leftover (or a FIFO / symlink planted there) is removed and
    # the file created exclusively, so the write never blocks on a FIFO or follows a link
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | os.O_CLOEXEC
    try:
        with os.fdopen(os.open(tmp, flags, 0o666), "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            if fsync:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    if fsync:
        with contextlib.suppress(OSError):
            fd = os.open(path.parent, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
