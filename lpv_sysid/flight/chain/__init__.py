"""TODO face"""

from __future__ import annotations

from lpv_sysid.flight.chain.steps import chain

__all__ = [
    "chain",
]
