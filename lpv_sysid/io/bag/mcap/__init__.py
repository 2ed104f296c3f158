"""The mcap storage file of a bag: its record primitives
(:mod:`~lpv_sysid.io.bag.mcap.records`), the index reader of a healthy file
(:mod:`~lpv_sysid.io.bag.mcap.index`), the record walk of an unfinished one
(:mod:`~lpv_sysid.io.bag.mcap.walk`) and its in-place repair
(:mod:`~lpv_sysid.io.bag.mcap.repair`).
"""

from __future__ import annotations

from lpv_sysid.io.bag.mcap.records import (
    MCAP_MAGIC,
    append_message,
    chunk_crc,
    write_chunk_crcs,
)

__all__ = [
    "MCAP_MAGIC",
    "append_message",
    "chunk_crc",
    "write_chunk_crcs",
]
