"""Per-vertex identification pipeline, seed 0 Sec. IV (Tables 1-3) -> ``vertex_models.yaml``.

For each scheduling vertex ``v_d`` (one phase-1 maneuver):

1. the flown trim ``x0, u0`` = mean over the trim-averaging window (seed 0 Table 1);
2. the same global smoother is applied to states and inputs and the states are
   differentiated (:mod:`lpv_sysid.ident.derivatives`), edges of the record are dropped;
3. perturbation variables ``dx = x - x0``, ``du = u - u0`` over the excitation segment;
4. known elements of ``A, B`` (kinematics, gravity, ``v x omega``, ``I omega x omega``) from
   the model's analytic linearisation, unknown masks from ``Quadrotor.unknown_masks()``
   (seed 0 Appendix A); equation-error LS (Appendix B), by default (``model: taylor2``) with
   the known part nonlinear and the exact second-order remainders of Eq. (6) as nuisance
   regressors (:mod:`lpv_sysid.ident.vertex.taylor`), an intercept per row, and the rotor reaction
   torque on the measured rotor acceleration;
5. the motor constants ``a_Omega, b_Omega`` of Eq. (8) from the rotor speeds
   (:func:`lpv_sysid.ident.vertex.motor_rows.motor_design`: per rotor, stacked, gated while a rotor
   is pinned at a speed limit, with the command-to-rotor latency), where the data allow;
   otherwise uncertain with the estimate pooled over the other maneuvers
   (:func:`identify_vertices`);
6. all rows' covariance jointly (:func:`lpv_sysid.ident.equation_error.solve_rows`: stacked-
   score EWC sandwich, Student-t dof);
7. the flown trim is *not* an equilibrium (the vehicle fluctuates about it and the dynamics
   are nonlinear: the identified model's derivative there is a few cm/s^2, and the flown mean
   rotor speed sits 1-3 rad/s above trim), so the second-order model is re-expanded about its
   own equilibrium at the flown velocity (seed 0 Eq. 13), with the delta-method covariance of
   the Jacobians there (:func:`lpv_sysid.ident.vertex.taylor.reexpand`); that equilibrium is the
   vertex's ``x0, u0``;
8. intervals ``nominal +/- k std`` of every identified element (Eq. 22, std widened for the
   Student-t dof) and the reduced uncertain vertex systems (Eq. 23),
   :mod:`lpv_sysid.ident.vertex.uncertainty`.

The result serialises to the ``vertices`` entries of ``vertex_models.yaml`` (format ``@2``,
:mod:`lpv_sysid.io.formats`).  Truth coverage on simulated airframes:
:mod:`lpv_sysid.studies.coverage` and docs/identification_coverage.md.

Parts (each one job; :mod:`.pipeline` runs them):
:mod:`.config` (``identification.yaml``), :mod:`.types` (data in, results out,
the known model), :mod:`.segment` (trim window, fit segment, smoothed perturbations),
:mod:`.noise` (errors in variables), :mod:`.motor_rows` (Eq. 8 rows),
:mod:`.taylor2` (the ``taylor2`` fit and the re-expansion), :mod:`.output`
(the ``vertex_models.yaml`` document), :mod:`.taylor` (the second-order equation error
behind ``taylor2``), :mod:`.uncertainty` (the Eq. 22 box and the Eq. 23 uncertain systems).
"""

from __future__ import annotations

from lpv_sysid.ident.vertex.config import IdentificationConfig, parse_measurement_noise
from lpv_sysid.ident.vertex.motor_rows import motor_design, pinned
from lpv_sysid.ident.vertex.noise import regressor_noise_var
from lpv_sysid.ident.vertex.output import box_corners, vertex_models_dict, vertex_order
from lpv_sysid.ident.vertex.pipeline import (
    identify_vertex,
    identify_vertices,
    in_sample_metrics,
    pooled_motor,
    free_run,
    validate,
)
from lpv_sysid.ident.vertex.segment import equilibrium, fit_indices, trim_window
from lpv_sysid.ident.vertex.types import VertexData, VertexResult, known_from_quadrotor
from lpv_sysid.ident.vertex.uncertainty import (
    DEFAULT_JOINT_PROBABILITY,
    UncertaintyConfig,
    applied_k,
    joint_k,
    sidak_k,
)

__all__ = [
    "IdentificationConfig",
    "UncertaintyConfig",
    "VertexData",
    "VertexResult",
    "applied_k",
    "joint_k",
    "DEFAULT_JOINT_PROBABILITY",
    "box_corners",
    "equilibrium",
    "fit_indices",
    "identify_vertex",
    "identify_vertices",
    "in_sample_metrics",
    "known_from_quadrotor",
    "motor_design",
    "parse_measurement_noise",
    "pinned",
    "pooled_motor",
    "regressor_noise_var",
    "sidak_k",
    "trim_window",
    "free_run",
    "validate",
    "vertex_models_dict",
    "vertex_order",
]
