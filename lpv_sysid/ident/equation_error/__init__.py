"""Equation-error grey-box least squares, seed 0 Appendix B (Eqs. 35-47).

For the perturbation state equation ``dxdot = A dx + B du`` (Eq. 35, with ``dx = x - x0``,
``du = u - u0``) some elements of ``A`` and ``B`` are known (kinematics, gravity, motor model)
and the others are unknown (functions of the aerodynamic parameters K).  Per row ``i``:

* index sets of unknown/known elements, Eqs. (36)-(39): ``maskA[i]``, ``maskB[i]`` (True =
  unknown) and their complements;
* regressors ``h_i = [x_j^T  u_k^T]`` over the unknown columns, Eq. (40) -> ``H_i`` (K x p_i),
  Eq. (45);
* measurement ``y_i = xdot_i - sum_known A_ij x_j - sum_known B_ik u_k``, Eq. (41);
* parameters ``theta^(i)`` = unknown elements of row i of ``[A B]``, Eq. (42);
* estimate ``theta^(i) = (H_i^T H_i)^-1 H_i^T y_i``, Eq. (47), computed with
  ``numpy.linalg.lstsq`` (SVD) instead of forming ``(H^T H)^-1``: the normal equations
  square the condition number of ``H`` (regressors in rad, m/s and ~600 rad/s rotor speeds
  differ by orders of magnitude), while the SVD solves the same problem in the conditioning
  of ``H`` itself.  Columns are scaled to unit norm first (the solution is unscaled after),
  and a rank-deficient ``H_i`` (regressor never excited) raises :class:`SolverError` naming
  the row and columns instead of returning a minimum-norm guess.

Uncertainty (white, ``residual_acf`` and ``ewc`` covariance estimates, :func:`t_factor`,
:func:`upper_quantile`): :mod:`~lpv_sysid.ident.equation_error.covariance`; solving the rows
and their joint covariance (:class:`RowFit`, :func:`fit_row`, :func:`solve_rows`, ``R^2`` per row):
:mod:`~lpv_sysid.ident.equation_error.solve`.  :mod:`~lpv_sysid.ident.equation_error.regression`
builds the row designs from the state equation and assembles ``A, B``.

All inputs are plain arrays; building them from bags is :mod:`lpv_sysid.ident.dataprep`.
"""

from __future__ import annotations

from lpv_sysid.ident.equation_error.covariance import (
    CovarianceConfig,
    default_dof,
    t_factor,
    upper_quantile,
)
from lpv_sysid.ident.equation_error.regression import (
    Fit,
    RowDesign,
    append_independent,
    assemble,
    fit,
    row_designs,
)
from lpv_sysid.ident.equation_error.solve import RowFit, fit_row, solve_rows

__all__ = [
    "CovarianceConfig",
    "Fit",
    "RowDesign",
    "RowFit",
    "append_independent",
    "assemble",
    "default_dof",
    "fit",
    "fit_row",
    "row_designs",
    "solve_rows",
    "t_factor",
    "upper_quantile",
]
