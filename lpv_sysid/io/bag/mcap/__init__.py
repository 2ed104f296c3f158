"""TODO face"""

from __future__ import annotations

from lpv_sysid.io.bag.mcap.records import append_message

__all__ = [
    "append_message",
]
