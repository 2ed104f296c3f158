"""Robust polytopic H-infinity state feedback: seed 0 Lemma 1, Eqs. (29)-(31).

For every scheduling vertex i and uncertainty vertex j (Eq. 23) find X_i^j = X_i^j^T > 0,
S_i and one common (general square) H with

    [ U + U^T          -X + H^T - U    B_e^j   H^T C^T ]
    [ -X + H - U^T     -(H + H^T)      0       -H^T C^T]
    [ B_e^j^T          0               -I      0       ]   < 0,     U = A_i^j H + B_c^j S_i   (30)
    [ C H              -C H            0       -g I    ]

with g = gamma^2; then K_i = S_i H^-1 (Eq. 31) gives ||u_e -> z||_inf < gamma for all v_d in the
box and all theta in the uncertainty box -- provided B_c^j is common to all scheduling vertices
(``model.common_input``, the product polytope of :mod:`lpv_sysid.models.lpv`, whose docstring
gives the interior argument); with per-vertex B_i^j only the vertices are certified. (Eq. 30 is
Phi0 + He([A;I;0;C] H [I,-I,0,0]) with the
dual bounded-real-lemma matrix Phi0; eliminating H recovers A X + X A^T + B_e B_e^T + X C^T C X /
g < 0.)

The parts: :mod:`~lpv_sysid.synthesis.hinf.options` (options, problem size, result),
:mod:`~lpv_sysid.synthesis.hinf.lemma1_numeric` (weights, Eq. (30) in numpy, the independent
re-check, the seed's problem sizes), :mod:`~lpv_sysid.synthesis.hinf.lemma1_cvxpy` (Eq. (30) as a
cvxpy problem and its solution read back), :mod:`~lpv_sysid.synthesis.hinf.box` (``method: box``,
the element-box LMI). :mod:`~lpv_sysid.synthesis.hinf.synthesize` drives the solvers
(:func:`solve_lemma1`) and, on failure, the remedies (:func:`synthesize_hinf`).

If the problem is infeasible at the requested gamma, the remedies of seed 0 Sec. VI are quantified.
Scaling R by c (B_e -> c B_e, Eq. 27) maps a solution (X, S, H) at gamma to c^2 (X, S, H) at
c gamma: the new Eq. (30) matrix is the congruence diag(cI, cI, I, cI) of the old one, and K = S
H^-1
is unchanged. The same holds for Q -> Q / c (C -> c C, Eq. 28) with (X, S, H) kept and the
congruence
diag(I, I, I, I/c). So the LMI feasible set is exactly
{gamma >= c gamma_min}: the factor by which the excitation magnitudes Delta_t..Delta_r must shrink
(or Delta_u..Delta_w grow) is gamma_min / gamma_req, read off one gamma minimisation; a bisection
on c would return the same number. Reducing the model uncertainty (remedy 3) is not homogeneous and
is quantified by bisection on the shrink factor rho of the uncertainty vertices about the nominal
(A_i^j -> A_i + rho (A_i^j - A_i)).
"""

from __future__ import annotations

from lpv_sysid.synthesis.hinf.box import resolve_method
from lpv_sysid.synthesis.hinf.lemma1_numeric import (
    certificate_margins,
    eq30_matrix,
    excitation_R,
    output_Q,
    performance_matrix,
    seed_problem_size,
)
from lpv_sysid.synthesis.hinf.norm import hinf_norm, hinf_norm_sweep, sigma_max
from lpv_sysid.synthesis.hinf.options import HinfOptions
from lpv_sysid.synthesis.hinf.synthesize import remedy_analysis, solve_lemma1, synthesize_hinf

__all__ = [
    "HinfOptions",
    "certificate_margins",
    "eq30_matrix",
    "excitation_R",
    "hinf_norm",
    "hinf_norm_sweep",
    "output_Q",
    "performance_matrix",
    "remedy_analysis",
    "resolve_method",
    "seed_problem_size",
    "sigma_max",
    "solve_lemma1",
    "synthesize_hinf",
]
