"""The CDR block codec of the bag readers and writers: fixed-layout records decoded and
encoded a topic at a time (:mod:`~lpv_sysid.io.bag.cdr.layout`) and message objects built
from decoded columns (:mod:`~lpv_sysid.io.bag.cdr.builder`).
"""

from __future__ import annotations

from lpv_sysid.io.bag.cdr.layout import CdrLayout, LayoutError, encode_block, records_close

__all__ = [
    "CdrLayout",
    "LayoutError",
    "encode_block",
    "records_close",
]
