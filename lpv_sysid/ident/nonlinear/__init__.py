"""Nonlinear aerodynamic model identification: seed 0 Eq. (6) from (phase-2) flight data.

Step 1 - linear regression.  Eq. (6) is linear in the lumped parameters K, so with the
measured generalised force (Eq. 3c/3d solved for F and M)

    F = m (v' - v x omega - g R_IB^T e3),      M = I omega' - (I omega) x omega

each axis is an ordinary least-squares problem ``f_axis = Phi_axis K_axis`` with the
regressors of :data:`REGRESSORS` (``delta = Mix Omega``, ``delta^2 = Mix Omega^2``, Eq. 7).
The rotor reaction torque ``J_z delta_r'`` in ``M_z`` uses the known ``j_rotor`` and is
moved to the measured side.  Solved with :func:`lpv_sysid.ident.equation_error.fit_row`
(SVD, standard errors with the coloured-residual correction, R^2); the regressor
correlation matrix per axis is seed 0 Fig. 10.

Step 2 - output-error refinement in the spirit of seed 2 Sec. 4 (Eqs. 70, 89, 95, 101):
``min_K sum_segments sum_k ||W (nu(k) - nu_hat(k; K))||^2`` with ``nu = (v, omega)``, where
``nu_hat`` integrates Eqs. (3c)-(3d) with the Eq. (6) model over short segments (default
1 s) starting from the measured ``nu``, driven by the *measured* attitude (gravity term) and
rotor speeds - as seed 2 drives each sub-model with the measured neighbouring states.  Short
segments keep the unstable vehicle's open-loop prediction bounded.  Solved with
``scipy.optimize.least_squares`` (trust-region reflective) from the regression estimate;
parameter standard errors from the Gauss-Newton covariance ``s^2 (J^T J)^-1``.

Parts: step 1 is :mod:`~lpv_sysid.ident.nonlinear.least_squares`; the others:

- :mod:`~lpv_sysid.ident.nonlinear.data`: ``AXES``, ``REGRESSORS``, ``regressors``,
  ``FlightData``, ``flight_data``, ``generalized_force`` and the result types ``AxisFit``,
  ``NonlinearResult``;
- :mod:`~lpv_sysid.ident.nonlinear.refinement`: step 2 (``OutputErrorConfig``,
  ``simulate_segments``, ``output_error``);
- :mod:`~lpv_sysid.ident.nonlinear.px4_model` and
  :mod:`~lpv_sysid.ident.nonlinear.px4_data`: the documented PX4 variant of Eq. (6)
  (motor outputs instead of rotor speeds, specific force and angular acceleration, the
  motor lag identified), its flight records (made from PX4 bags by
  ``ident.dataprep.px4_record``), prediction of another flight
  (R^2, TIC) and the physical quantities compared with PX4 SIH's parameters.
"""

from __future__ import annotations

from lpv_sysid.ident.nonlinear.correlation import (
    AXIS_TITLES,
    REGRESSOR_NAMES,
    RegressorCorrelation,
    column_correlation,
    fig10_regressors,
    regressor_correlations,
)
from lpv_sysid.ident.nonlinear.data import (
    AXES,
    REGRESSORS,
    FlightData,
    flight_data,
    gravity_body,
    regressors,
    virtual_actuators,
)
from lpv_sysid.ident.nonlinear.least_squares import regression, regression_stacked
from lpv_sysid.ident.nonlinear.px4_data import Px4Record, motor_lag
from lpv_sysid.ident.nonlinear.px4_model import (
    PHYSICAL,
    PX4_AXES,
    PX4_OUTPUTS,
    PX4_REGRESSORS,
    SIH_DEFAULTS,
    Prediction,
    Px4Model,
    identify_px4,
    physical_quantities,
    predict,
    sih_truth,
)
from lpv_sysid.ident.nonlinear.refinement import OutputErrorConfig, output_error

__all__ = [
    "AXES",
    "PHYSICAL",
    "PX4_AXES",
    "PX4_OUTPUTS",
    "PX4_REGRESSORS",
    "Prediction",
    "Px4Model",
    "Px4Record",
    "SIH_DEFAULTS",
    "identify_px4",
    "motor_lag",
    "physical_quantities",
    "predict",
    "sih_truth",
    "AXIS_TITLES",
    "FlightData",
    "OutputErrorConfig",
    "REGRESSORS",
    "REGRESSOR_NAMES",
    "RegressorCorrelation",
    "column_correlation",
    "fig10_regressors",
    "flight_data",
    "gravity_body",
    "output_error",
    "regression",
    "regression_stacked",
    "regressor_correlations",
    "regressors",
    "virtual_actuators",
]
