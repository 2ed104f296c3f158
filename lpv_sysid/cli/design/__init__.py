"""Offline design commands (a laptop, no vehicle): ``signals``, ``simulate``, ``identify``,
``identify-nonlinear``, ``synthesize``, ``verify``, ``vrft``, ``coverage``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lpv_sysid.cli.design.identify import load_config, quadrotor_section
    from lpv_sysid.cli.design.simulate import format_gain_line, run_phase2
    from lpv_sysid.cli.design.synthesize import with_flag

#: the part that defines each exported name, imported when the name is first used: a run of
#: one command (``lpv-sysid verify``) does not import synthesize's cvxpy/scipy chain
_PART = {
    "format_gain_line": "simulate",
    "load_config": "identify",
    "quadrotor_section": "identify",
    "run_phase2": "simulate",
    "with_flag": "synthesize",
}


def __getattr__(name: str) -> Any:
    part = _PART.get(name)
    if part is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{part}"), name)


__all__ = [
    "format_gain_line",
    "load_config",
    "quadrotor_section",
    "run_phase2",
    "with_flag",
]
