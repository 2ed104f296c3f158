"""SHA-256 of files and bytes: the one hash the package records for what it read or wrote.

Used for ``certificate.models_sha256`` (the models file the gains were synthesised for), the
certificate sidecar entry ``certificate.sidecar.sha256``, the recorder's session manifest
(gains file of a flight) and the signal files' provenance.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Union

PathLike = Union[str, "os.PathLike[str]"]


def sha256_bytes(data: bytes) -> str:
    """SHA-256 (hex) of ``data``."""
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: PathLike) -> str:
    """SHA-256 (hex) of the bytes of ``path``, read in chunks through
    :func:`lpv_sysid.io.files.opening.open_regular` (regular files only: a FIFO would block; at
    most
    :data:`~lpv_sysid.io.files.opening.MAX_NPZ_BYTES`, the larger of the package's read caps).
    Every failure is a ConfigError naming the file."""
    from lpv_sysid.io.files.opening import MAX_NPZ_BYTES, open_regular

    h = hashlib.sha256()
    with open_regular(path, Path(path).name, max_bytes=MAX_NPZ_BYTES, show_path=True) as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
