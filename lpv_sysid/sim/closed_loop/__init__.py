"""LPV closed loop of seed 0 Eq. (33) at nominal parameters theta0.

    x' = A(v_d, theta0) (x - x0(v_d)) + B_c(theta0) (u_c - u0(v_d)) + B_e(theta0) kappa u_e + x0'

with the static LPV state feedback of Eq. (31), ``u_c = u0(v_d) + K(v_d) (x - x0(v_d))``,
``B_e = B_c R`` (Eq. 19), the equilibrium rate of Eq. (34), ``x0' = dx0/dv_d * dv_d/dt``, and
the performance output of Eq. (18), ``z = Q^-1 (v - v_d)``. Eq. (19b) writes it as
``z = C dx = Q^-1 (v - v0(v_d))``, which is the same signal when the equilibrium velocity
``v0(v_d)`` of the vertex models equals ``v_d``; identified equilibria need not (seed 0 Table 1),
so both are reported: ``z`` / ``gain`` (Eq. 18) and ``z_model`` / ``gain_model`` (Eq. 19b, the
output the Lemma 1 certificate bounds).
Because ``B_e kappa u_e = B_c R kappa u_e`` the right-hand side is evaluated as
``A dx + B (u - u0) + x0'`` with the total command ``u = u_c + R kappa u_e`` (Eq. 17); a
saturating law can therefore be plugged in unchanged.

The scheduled quantities ``A(v_d), B(v_d), K(v_d), x0(v_d), u0(v_d), dx0/dv_d`` come from an
object implementing :class:`ScheduledModel` (in the product: the multilinear interpolation of
``lpv_sysid.models.lpv`` over the vertices of ``vertex_models.yaml`` and ``gains.yaml``; see
:mod:`lpv_sysid.sim.phase2`). This module never interpolates by itself.

Signals are first-order hold (:mod:`lpv_sysid.sim.closed_loop.references`), so Eq. (34) is exact
for the interpolated reference.

Reference feedforward (synthesis/feedforward.py, seed 2 Sec. 5.1). Eq. (33) is kept as the
seed's: its ``x0'`` term moves the equilibrium with v_d for free, so the reference is already a
trajectory of Eq. (33) by construction and the seed's law needs no feedforward there (adding the
feedforward *and* keeping ``x0'`` would ask for the acceleration twice). The linear counterpart
of the real vehicle drops ``x0'`` (``moving_equilibrium=False``: ``x' = A (x - x0) + B (u - u0)``,
the equilibrium does not move by itself) and flies :func:`feedforward_law`,
``u = u0 + du_ff + K (x - x0 - dx_ff) + R kappa u_e``: there the feedforward has to make the
reference a trajectory, which it does by construction of F_i from the same (A_i, B_i) up to the
neglected dF/dt and snap terms; :mod:`lpv_sysid.sim.phase2` reports it as ``linear_ff``.

Parts: :mod:`~lpv_sysid.sim.closed_loop.eq33` (the loop itself),
:mod:`~lpv_sysid.sim.closed_loop.schedule` (the ``ScheduledModel`` protocol, fast weights, the
last-point cache),
:mod:`~lpv_sysid.sim.closed_loop.references` (first-order hold of v_d and u_e),
:mod:`~lpv_sysid.sim.closed_loop.laws` (the laws of Eqs. 17, 31 and the feedforward law),
:mod:`~lpv_sysid.sim.closed_loop.fused` (the fused evaluation used for the product's models and
laws),
:mod:`~lpv_sysid.sim.closed_loop.integrate` (RK45 / RK4 on the signal grid) and
:mod:`~lpv_sysid.sim.closed_loop.hinf_grid` (the LMI-free frequency-grid check of Eq. 29).
"""

from __future__ import annotations

from lpv_sysid.sim.closed_loop.eq33 import (
    VELOCITY_INDEX,
    ClosedLoopResult,
    eq33_rhs,
    l2_norm,
    performance_matrix,
    simulate_eq33,
    x0_dot,
)
from lpv_sysid.sim.closed_loop.excitation_fir import excitation_response_fir
from lpv_sysid.sim.closed_loop.fused import fused_eq33
from lpv_sysid.sim.closed_loop.hinf_grid import hinf_norm_grid
from lpv_sysid.sim.closed_loop.integrate import ClosedLoopConfig
from lpv_sysid.sim.closed_loop.laws import (
    ControlLaw,
    FeedforwardSchedule,
    feedforward_law,
    linear_lpv_law,
)
from lpv_sysid.sim.closed_loop.references import ReferenceSignals

__all__ = [
    "ClosedLoopConfig",
    "ClosedLoopResult",
    "ControlLaw",
    "FeedforwardSchedule",
    "ReferenceSignals",
    "VELOCITY_INDEX",
    "eq33_rhs",
    "excitation_response_fir",
    "feedforward_law",
    "fused_eq33",
    "hinf_norm_grid",
    "l2_norm",
    "linear_lpv_law",
    "performance_matrix",
    "simulate_eq33",
    "x0_dot",
]
