"""Offline design commands (a laptop, no vehicle): ``signals``, ``simulate``, ``identify``,
``identify-nonlinear``, ``synthesize``, ``verify``, ``vrft``, ``coverage``.
"""

from __future__ import annotations

from lpv_sysid.cli.design.identify import load_config, quadrotor_section
from lpv_sysid.cli.design.simulate import format_gain_line, run_phase2
from lpv_sysid.cli.design.synthesize import with_flag

__all__ = [
    "format_gain_line",
    "load_config",
    "quadrotor_section",
    "run_phase2",
    "with_flag",
]
