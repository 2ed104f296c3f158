"""Step 1 of the nonlinear identification: per-axis least squares on the Eq. (6) regressors
(:func:`regression`, :func:`regression_stacked`); the method is the
:mod:`lpv_sysid.ident.nonlinear` docstring."""

from __future__ import annotations

import numpy as np

from lpv_sysid.errors import SolverError
from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident.nonlinear.correlation import column_correlation
from lpv_sysid.ident.nonlinear.data import (
    AXES,
    REGRESSORS,
    AxisFit,
    FlightData,
    NonlinearResult,
    _check,
    generalized_force,
    regressors,
)


def regression(
    data: FlightData,
    params,
    max_lag: int | None = None,
    fixed: dict[str, float] | None = None,
    smoother=None,
    keep: slice | None = None,
) -> NonlinearResult:
    """Step 1: per-axis least squares of Eq. (6) on the measured generalised force.

    ``fixed`` maps K names to known values; their regressors move to the measured side
    (e.g. the ``*_mu0`` terms when the data cannot separate them from ``*_T0``).

    With measured data, ``data`` holds the *raw* states and the smoothed derivatives of
    :func:`flight_data`; ``smoother`` (the same filter) is then applied to every nonlinear
    term (regressors, ``v x omega``, gravity, gyroscopic moment) computed from the raw
    states, so that the filtered equation holds exactly (``L[phi(x)]``, not ``phi(L[x])``),
    and ``keep`` drops the filter's edge samples.
    """
    return regression_stacked([(data, smoother, keep)], params, max_lag, fixed)


def _axis_data(data: FlightData, params, smoother, keep):
    """Per-axis measured generalised force component and regressor matrix (filtered, cut)."""
    from lpv_sysid.models.quadrotor import mixer

    _check(data)
    mix = mixer(params.arm_length)
    regs = regressors(data.v, data.omega, data.Omega, data.Omega_dot, params.arm_length, mix)
    F, M = generalized_force(data, params, smoother)
    ddr = data.Omega_dot @ mix[3]
    if smoother is not None:
        regs = {a: smoother(r) for a, r in regs.items()}
    if keep is not None:
        regs = {a: r[keep] for a, r in regs.items()}
        F, M, ddr = F[keep], M[keep], ddr[keep]
    meas = {
        "X": F[:, 0],
        "Y": F[:, 1],
        "Z": F[:, 2],
        "L": M[:, 0],
        "M": M[:, 1],
        "N": M[:, 2] - params.j_rotor * ddr,
    }
    return meas, regs


def regression_stacked(
    records, params, max_lag: int | None = None, fixed: dict[str, float] | None = None
) -> NonlinearResult:
    """:func:`regression` over several records ``[(data, smoother, keep), ...]`` stacked
    row-wise (one least-squares problem per axis over all records)."""
    fixed = dict(fixed or {})
    parts = [_axis_data(d, params, sm, kp) for d, sm, kp in records]
    K, std, axes = {}, {}, {}
    for ax in AXES:
        names = [nm for nm, _ in REGRESSORS[ax]]
        labels = [lb for _, lb in REGRESSORS[ax]]
        y = np.concatenate([m[ax] for m, _ in parts])
        R = np.concatenate([r[ax] for _, r in parts])
        free = [c for c, nm in enumerate(names) if nm not in fixed]
        for c, nm in enumerate(names):
            if nm in fixed:
                y = y - R[:, c] * fixed[nm]
                K[nm], std[nm] = float(fixed[nm]), 0.0
        H = R[:, free]
        if y.size <= len(free):
            raise SolverError(f"axis {ax}: {y.size} samples for {len(free)} parameters")
        rf = ee.fit_row(AXES.index(ax), y, H, tuple(range(len(free))), (), max_lag)
        for j, c in enumerate(free):
            K[names[c]] = float(rf.theta[j])
            std[names[c]] = float(rf.std[j])
        axes[ax] = AxisFit(
            ax,
            tuple(names[c] for c in free),
            tuple(labels[c] for c in free),
            rf.theta,
            rf.std,
            rf.r2,
            column_correlation(H),
        )
    return NonlinearResult(K, std, axes)
