"""One synthesis from the vertex models to a certified gains file (``lpv-sysid synthesize``,
the chain's step 4): the configuration file declared once
(:mod:`~lpv_sysid.synthesis.gains.config`), inputs (options, models, weights, design
envelope; :mod:`~lpv_sysid.synthesis.gains.inputs`), the solve and the independent verification of
what was written (:mod:`~lpv_sysid.synthesis.gains.pipeline`), the certificate entry
(:mod:`~lpv_sysid.synthesis.gains.certificate`), the files
(:mod:`~lpv_sysid.synthesis.gains.outputs`) and gains that cover the loop that flies them
(:mod:`~lpv_sysid.synthesis.gains.loop_cover`).
"""

from __future__ import annotations

from lpv_sysid.synthesis.gains.config import (
    FeedforwardSection,
    LoopDelaySection,
    SynthesisConfig,
    VerifySection,
    WeightsSection,
)
from lpv_sysid.synthesis.gains.inputs import design_from_summary, load_inputs
from lpv_sysid.synthesis.gains.loop_cover import REGION_SCALES, cover_loop
from lpv_sysid.synthesis.gains.outputs import write_gains
from lpv_sysid.synthesis.gains.pipeline import describe_problem, synthesize, verify_written

__all__ = [
    "FeedforwardSection",
    "LoopDelaySection",
    "REGION_SCALES",
    "SynthesisConfig",
    "VerifySection",
    "WeightsSection",
    "describe_problem",
    "cover_loop",
    "design_from_summary",
    "load_inputs",
    "synthesize",
    "verify_written",
    "write_gains",
]
