"""Excitation: the phase-1 reference of seed 0 Sec. IV (:func:`phase1_signals`,
:func:`phase1_reference`) and the public names of the excitation player, which plays a
signal set as velocity/yaw-rate reference and excitation u_e (no ROS here; the core
behind ``excitation_node``):

* :mod:`lpv_sysid.signals.excitation.player` - :class:`ExcitationCore` (timeline, fades,
  abort, O(1) lookup) and the channels of the two experiments of seed 0;
* :mod:`lpv_sysid.signals.excitation.clock` - :class:`TimeOrderError`, :class:`MonotonicTime`;
* :mod:`lpv_sysid.signals.excitation.envelope` - :func:`design_envelope` (the bounds the
  gains record in ``certificate.design``) and :func:`check_design`.
"""

from __future__ import annotations

from lpv_sysid.signals.excitation.clock import MonotonicTime, TimeOrderError
from lpv_sysid.signals.excitation.envelope import check_design, design_envelope, envelope_dict
from lpv_sysid.signals.excitation.phase1 import phase1_reference, phase1_signals
from lpv_sysid.signals.excitation.player import (
    ABORTED,
    DEFAULT_RAMP_S,
    DONE,
    IDLE,
    PHASE1_CHANNELS,
    PHASE1_YAW_CHANNEL,
    PHASE2_CHANNELS,
    PHASE2_EXCITATION,
    RAMP_IN,
    RAMP_OUT,
    RUNNING,
    ExcitationCore,
)

__all__ = [
    "ABORTED",
    "DEFAULT_RAMP_S",
    "DONE",
    "ExcitationCore",
    "IDLE",
    "MonotonicTime",
    "PHASE1_CHANNELS",
    "PHASE1_YAW_CHANNEL",
    "PHASE2_CHANNELS",
    "PHASE2_EXCITATION",
    "RAMP_IN",
    "RAMP_OUT",
    "RUNNING",
    "TimeOrderError",
    "check_design",
    "design_envelope",
    "envelope_dict",
    "phase1_reference",
    "phase1_signals",
]
