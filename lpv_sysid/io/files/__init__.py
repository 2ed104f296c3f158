"""TODO face"""

from __future__ import annotations

from lpv_sysid.io.files.hashing import sha256_file
from lpv_sysid.io.files.opening import (
    MAX_YAML_BYTES,
    check_output,
    check_regular,
    decode_text,
    open_regular,
    read_bytes,
    read_npz,
    read_text,
)
from lpv_sysid.io.files.yaml_loader import MAX_MAGNITUDE, strict_load
from lpv_sysid.io.files.yaml_reader import read_located, read_yaml, read_yaml_mapping, save_yaml

__all__ = [
    "MAX_MAGNITUDE",
    "MAX_YAML_BYTES",
    "check_output",
    "check_regular",
    "decode_text",
    "open_regular",
    "read_bytes",
    "read_located",
    "read_npz",
    "read_text",
    "read_yaml",
    "read_yaml_mapping",
    "save_yaml",
    "sha256_file",
    "strict_load",
]
