"""TODO face"""

from __future__ import annotations

from lpv_sysid.synthesis.gains.certificate import (
    LMI_TEXT,
    VARIATION,
    certificate_entry,
    certified_set_entry,
    problem_entry,
)
from lpv_sysid.synthesis.gains.inputs import (
    Inputs,
    design_from_summary,
    feedforward_settings,
    load_config,
    load_inputs,
    velocity_index,
    weights_from_config,
)
from lpv_sysid.synthesis.gains.outputs import feedforward_terms, print_result, write_outputs

__all__ = [
    "Inputs",
    "LMI_TEXT",
    "VARIATION",
    "certificate_entry",
    "certified_set_entry",
    "design_from_summary",
    "feedforward_settings",
    "feedforward_terms",
    "load_config",
    "load_inputs",
    "print_result",
    "problem_entry",
    "velocity_index",
    "weights_from_config",
    "write_outputs",
]
