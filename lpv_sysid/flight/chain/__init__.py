"""TODO face"""

from __future__ import annotations

from lpv_sysid.flight.chain.report import format_identification, write_report

__all__ = [
    "format_identification",
    "write_report",
]
