"""TODO face"""

from __future__ import annotations

from lpv_sysid.synthesis.gains.inputs import design_from_summary, load_inputs
from lpv_sysid.synthesis.gains.outputs import write_gains
from lpv_sysid.synthesis.gains.pipeline import describe_problem, synthesize, verify_written

__all__ = [
    "describe_problem",
    "design_from_summary",
    "load_inputs",
    "synthesize",
    "verify_written",
    "write_gains",
]
