"""What the vertex identification (:mod:`lpv_sysid.ident.vertex`) takes and returns: the
aligned arrays of one maneuver, the known part of its perturbation model (seed 0 Appendix
A/B) and the identified vertex with its ``vertex_models.yaml`` entry."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident.vertex import uncertainty as unc


@dataclass(frozen=True)
class VertexData:
    """Aligned arrays of one phase-1 maneuver on a uniform grid (from dataprep or a simulator)."""

    t: np.ndarray  # (N,) s
    x: np.ndarray  # (N, 12) STATE_NAMES
    u: np.ndarray  # (N, 4) INPUT_NAMES
    scheduling: np.ndarray  # (3,) commanded vertex v_d
    trim: tuple[float, float]  # [t_start, t_end) of the trim segment
    fit: tuple[float, float]  # [t_start, t_end) of the excitation (fit) segment
    name: str = ""
    u_eff: np.ndarray | None = None  # (N, 4) command after the ESC clip of Eq. (8) (None: from u)
    motor_identifiable: bool = True  # rotor speeds measured and u independent of them


@dataclass(frozen=True)
class KnownModel:
    """Known elements and unknown masks of the perturbation model (seed 0 Appendix A/B)."""

    A: np.ndarray
    B: np.ndarray
    maskA: np.ndarray
    maskB: np.ndarray


@dataclass(frozen=True)
class VertexResult:
    name: str
    scheduling: np.ndarray
    x0: np.ndarray  # operating point of the model (the identified equilibrium, taylor2)
    u0: np.ndarray
    fit: ee.Fit
    uncertain: unc.UncertainVertex
    r2_axes: dict
    validation: dict = field(default_factory=dict)
    x_flown: np.ndarray | None = None  # mean over the trim window (seed 0 Table 1)
    u_flown: np.ndarray | None = None
    xdot_flown: np.ndarray | None = (
        None  # identified model's derivative there (not an equilibrium)
    )
    motor: dict = field(default_factory=lambda: {"mode": "known"})  # how a_Omega, b_Omega entered

    def to_dict(self) -> dict:
        """One ``vertices`` entry of ``vertex_models.yaml`` (format ``@2``,
        io/formats/vertex_models.py).

        ``uncertain`` lists every identified element (aerodynamic rows and, when identified,
        the motor rows ``A[8:12, 8:12] = -a_Omega I``, ``B[8:12, :] = b_Omega I``) with its
        calibrated standard error and the interval ``nominal +/- k std`` of Eq. (22), ``k`` =
        ``meta.k_sigma`` (``meta.uncertainty.k_applied`` when raised by ``joint_alpha``).  The
        reduced polytope of :mod:`lpv_sysid.ident.vertex.uncertainty` is not stored; a consumer
        that wants it applies the reduction to these intervals.
        """
        fit = {"r2": {k: float(v) for k, v in self.r2_axes.items()}}
        for key in ("tic", "nrmse"):
            if key in self.validation:
                fit[key] = {k: float(v) for k, v in self.validation[key].items()}
        return {
            "scheduling": [float(v) for v in self.scheduling],
            "x0": [float(v) for v in self.x0],
            "u0": [float(v) for v in self.u0],
            "A": self.fit.A.tolist(),
            "B": self.fit.B.tolist(),
            "uncertain": [iv.to_dict() for iv in self.uncertain.intervals],
            "fit": fit,
        }


def known_from_quadrotor(x0: np.ndarray, params: dict | None = None) -> KnownModel:
    """Known elements = the truth model's linearisation at the measured trim ``x0`` at every
    element that does not depend on the aerodynamic parameters K (``unknown_masks``)."""
    from lpv_sysid.models.quadrotor import Quadrotor, QuadrotorParams

    model = Quadrotor(QuadrotorParams.from_dict(params) if params else QuadrotorParams())
    A, B = model.linearize(np.asarray(x0, dtype=float))
    maskA, maskB = model.unknown_masks()
    return KnownModel(np.where(maskA, 0.0, A), np.where(maskB, 0.0, B), maskA, maskB)
