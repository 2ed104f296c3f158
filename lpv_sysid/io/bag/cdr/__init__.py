"""TODO face"""

from __future__ import annotations

from lpv_sysid.io.bag.cdr.layout import CdrLayout, LayoutError, encode_block, records_close

__all__ = [
    "CdrLayout",
    "LayoutError",
    "encode_block",
    "records_close",
]
