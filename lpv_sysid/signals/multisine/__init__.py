"""Orthogonal phase-optimised multisines (seed 0 Sec. V; Morelli 2021, SIDPAC ``mkmsswp``).

Design of a signal set from a :class:`~lpv_sysid.signals.multisine.config.SignalsConfig`:

1. the period T fixes the frequency resolution f0 = 1/T; the harmonics ``k f0`` inside
   each group's band (skipping those already used by an earlier group) are dealt out
   interleaved, channel j of an n-channel group getting the j-th, (j+n)-th, ... of them,
   so no two channels share a frequency and all channels are mutually orthogonal over T;
2. each channel ``x_j(t) = sum_k a_k cos(2 pi h_k t / T + phi_k)`` starts from Schroeder
   phases and its relative peak factor is minimised over the phases
   (:mod:`lpv_sysid.signals.multisine.phase_opt`);
3. each channel is shifted in time by whole samples to an upward zero crossing, so it
   starts and ends near zero (a time shift changes phases only: RPF, spectrum and
   orthogonality are unchanged);
4. each channel is scaled to its configured peak, or the group to its configured energy
   (Eq. 26) with the power fractions; the weights R, Q of Eqs. (27)-(28) are attached.
"""

from __future__ import annotations

from lpv_sysid.signals.multisine.config import (
    MAX_DURATION,
    MAX_SAMPLE_RATE,
    PHASE1_DEFAULT,
    GroupConfig,
    SignalsConfig,
    load_config,
)
from lpv_sysid.signals.multisine.generator import SignalSet, allocate_harmonics, design
from lpv_sysid.signals.multisine.phase_opt import schroeder_phases, synthesize

__all__ = [
    "GroupConfig",
    "MAX_DURATION",
    "MAX_SAMPLE_RATE",
    "PHASE1_DEFAULT",
    "SignalSet",
    "SignalsConfig",
    "allocate_harmonics",
    "design",
    "load_config",
    "schroeder_phases",
    "synthesize",
]
