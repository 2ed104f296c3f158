"""Nonlinear quadrotor model of seed 0 (Hopwood & Woolsey), Eqs. (2), (3), (6), (7), (8).

Frames: NED world frame F_I, FRD body frame F_B (seed 0 Sec. II). Euler angles follow
R_IB = exp([e3x] psi) exp([e2x] theta) exp([e1x] phi) and the kinematics of Eq. (2).

Full state (16, ``FULL_STATE_NAMES``): position NED, Euler angles, body velocity, body
rates, rotor speeds Omega_1..4 (PX4 quad-X numbering: 1 front-right CCW, 2 rear-left CCW,
3 front-left CW, 4 rear-right CW). Controller state (12, ``STATE_NAMES``, seed 0 Eq. 14
without position and yaw) replaces Omega by the virtual actuators delta = Mix Omega.

Input: the virtual actuator command u = Mix u_ESC (seed 0 Eq. 8); per motor
u_ESC = clip(Mix^-1 u, 0, 1) and dOmega/dt = -a_Omega Omega + b_Omega u_ESC, with the rotor
speed held inside [omega_min, omega_max].

The squared virtual actuators are delta^2 = Mix Omega^2 (Eq. 7, not the square of delta).

Parts: the model object :class:`Quadrotor` (:mod:`~lpv_sysid.models.quadrotor.model`) and

- :mod:`~lpv_sysid.models.quadrotor.params`: ``QuadrotorParams``, the lumped aerodynamic
  parameters ``K`` of Eq. (6) (``K_NAMES``, ``DEFAULT_K``, table of regressors);
- :mod:`~lpv_sysid.models.quadrotor.states`: state/input/channel names, ``mixer`` (Eq. 7),
  ``reduced_state`` / ``full_state``;
- :mod:`~lpv_sysid.models.quadrotor.hot_path`: Eqs. (3), (6)-(8) as generated source,
  compiled per model (why code generation: that module's docstring);
- :mod:`~lpv_sysid.models.quadrotor.trim`: ``Trim`` and the equilibrium solver (Sec. III);
- :mod:`~lpv_sysid.models.quadrotor.linear`: analytic Jacobians (Eqs. 10-16) and the
  unknown-element masks (Appendix A).
"""

from __future__ import annotations

from lpv_sysid.models.quadrotor.model import Quadrotor
from lpv_sysid.models.quadrotor.params import DEFAULT_K, K_NAMES, QuadrotorParams
from lpv_sysid.models.quadrotor.states import (
    EXCITATION_NAMES,
    I_DR,
    INPUT_NAMES,
    INPUT_UNITS,
    SCHEDULING_NAMES,
    STATE_NAMES,
    STATE_UNITS,
    full_state,
    mixer,
    reduced_state,
)
from lpv_sysid.models.quadrotor.trim import Trim
from lpv_sysid.models.quadrotor.trim_table import SEED0_TABLE1, TRIM_COLUMNS, TRIM_TABLE

__all__ = [
    "DEFAULT_K",
    "EXCITATION_NAMES",
    "INPUT_NAMES",
    "INPUT_UNITS",
    "I_DR",
    "K_NAMES",
    "Quadrotor",
    "QuadrotorParams",
    "SCHEDULING_NAMES",
    "SEED0_TABLE1",
    "STATE_NAMES",
    "STATE_UNITS",
    "TRIM_COLUMNS",
    "TRIM_TABLE",
    "Trim",
    "full_state",
    "mixer",
    "reduced_state",
]
