"""The one place user-supplied files are opened, read and hashed: regular files only, size
caps, no pickles, atomic text writes (:mod:`~lpv_sysid.io.files.opening`); the strict YAML loader
(:mod:`~lpv_sysid.io.files.yaml_loader`) and the readers and atomic writer built on it
(:mod:`~lpv_sysid.io.files.yaml_reader`); SHA-256 of files
(:mod:`~lpv_sysid.io.files.hashing`). May import: :mod:`lpv_sysid.errors`.
"""

from __future__ import annotations

from lpv_sysid.io.files.hashing import sha256_file
from lpv_sysid.io.files.opening import (
    MAX_YAML_BYTES,
    atomic_write_text,
    check_output,
    check_regular,
    decode_text,
    open_regular,
    read_bytes,
    read_key,
    read_npz,
    read_text,
    refuse_existing,
    refuse_overwrite,
)
from lpv_sysid.io.files.yaml_loader import MAX_MAGNITUDE, strict_load
from lpv_sysid.io.files.yaml_reader import read_located, read_yaml, read_yaml_mapping, save_yaml

__all__ = [
    "MAX_MAGNITUDE",
    "MAX_YAML_BYTES",
    "atomic_write_text",
    "check_output",
    "check_regular",
    "decode_text",
    "open_regular",
    "read_bytes",
    "read_key",
    "read_located",
    "read_npz",
    "read_text",
    "read_yaml",
    "read_yaml_mapping",
    "refuse_existing",
    "refuse_overwrite",
    "save_yaml",
    "sha256_file",
    "strict_load",
]
