"""The quadrotor model object (:class:`Quadrotor`): parameters, mixer, the compiled Eq. (3)
right-hand side, trim and linearisation as methods; the model is the
:mod:`lpv_sysid.models.quadrotor` docstring."""

from __future__ import annotations

import logging

import numpy as np

from lpv_sysid.models.quadrotor import linear as quadrotor_linear
from lpv_sysid.models.quadrotor import trim as quadrotor_trim
from lpv_sysid.models.quadrotor.hot_path import (
    compile_hot_path,
    hot_path_constants,
)
from lpv_sysid.models.quadrotor.params import QuadrotorParams
from lpv_sysid.models.quadrotor.states import full_state, mixer
from lpv_sysid.models.quadrotor.trim import Trim

log = logging.getLogger(__name__)


class Quadrotor:
    """Seed 0 Eqs. (3), (6)-(8) with analytic linearisation (Eqs. 10-16).

    Hot path (plain floats, compiled per model from the equation sources of
    :mod:`lpv_sysid.models.quadrotor.hot_path`): ``derivatives_list(x16, u) -> list`` and
    ``rk4_step(x16, u, h) -> list`` (one classical RK4 step with ``u`` held), used by the
    simulators."""

    def __init__(self, params: QuadrotorParams | None = None) -> None:
        self.params = params if params is not None else QuadrotorParams()
        p = self.params
        self.mix = mixer(p.arm_length)
        self.mix_inv = np.linalg.inv(self.mix)
        self.inertia = np.array(p.inertia, dtype=float)
        self.inertia_inv = np.linalg.inv(self.inertia)
        # Plain-float hot path (numpy's per-call overhead dominates for 3- and 4-vectors):
        # the functions compiled from the equation sources, parameters bound.
        #: the parameter values the hot path is specialised on (name -> value)
        self.hot_path_constants = hot_path_constants(p, self.mix_inv, self.inertia_inv)
        self._fm, self._rotor_rates, self.derivatives_list, self.rk4_step = compile_hot_path(
            self.hot_path_constants
        )

    def __reduce__(self):
        return (Quadrotor, (self.params,))

    # ------------------------------------------------------------------ Eq. (6)
    def forces_moments(self, v, omega, Omega, Omega_dot=(0.0, 0.0, 0.0, 0.0)):
        """Applied force F and moment M in F_B (seed 0 Eq. 6) -> (F(3), M(3))."""
        F, M = self._fm(
            *[float(a) for a in v],
            *[float(a) for a in omega],
            *[float(a) for a in Omega],
            *[float(a) for a in Omega_dot],
        )
        return np.array(F), np.array(M)

    # ------------------------------------------------------------------ Eq. (8)
    def u_esc(self, u) -> np.ndarray:
        """Per-motor ESC command u_ESC = clip(Mix^-1 u, 0, 1) (seed 0 Eq. 8)."""
        return np.clip(self.mix_inv @ np.asarray(u, dtype=float), 0.0, 1.0)

    # ------------------------------------------------------------------ Eq. (3)
    # derivatives_list(x, u) -> list: the 16-state derivative on plain sequences (hot path)
    # rk4_step(x, u, h) -> list: one RK4 step of length h with u held (hot path)

    def derivatives(self, x16, u) -> np.ndarray:
        """Time derivative of the full 16-state model (seed 0 Eqs. 3, 6, 7, 8)."""
        x16 = np.asarray(x16, dtype=float)
        u = np.asarray(u, dtype=float)
        if x16.shape != (16,) or u.shape != (4,):
            raise ValueError(
                f"derivatives: expected x (16,) and u (4,), got {x16.shape}, {u.shape}"
            )
        return np.array(self.derivatives_list(x16.tolist(), u.tolist()))

    def derivatives12(self, controller_state, u) -> np.ndarray:
        """Time derivative of the 12-state controller model (delta = Mix Omega)."""
        x16 = full_state(controller_state, arm_length=self.params.arm_length)
        d16 = self.derivatives(x16, u)
        return np.concatenate([d16[3:5], d16[6:12], self.mix @ d16[12:16]])

    def specific_force(self, x16, u) -> np.ndarray:
        """Accelerometer specific force F/m in F_B (what an ideal IMU at the CG measures)."""
        x16 = np.asarray(x16, dtype=float)
        Od = self._rotor_rates(x16[12:16].tolist(), np.asarray(u, dtype=float).tolist())
        F, _ = self._fm(*x16[6:12].tolist(), *x16[12:16].tolist(), *Od)
        return np.array(F) / self.params.mass

    # ------------------------------------------------------------------ trim, Jacobians
    def trim(self, v_body, yaw_rate: float = 0.0) -> Trim:
        """Equilibrium for body velocity v_d and yaw rate psi-dot (seed 0 Sec. III);
        :func:`lpv_sysid.models.quadrotor.trim.trim`."""
        return quadrotor_trim.trim(self, v_body, yaw_rate)

    def linearize(self, trim_or_x, u0=None):
        """Analytic Jacobians A (12x12), B (12x4) of the 12-state model (seed 0 Eqs. 10-16);
        :func:`lpv_sysid.models.quadrotor.linear.linearize`."""
        return quadrotor_linear.linearize(self, trim_or_x, u0)

    def unknown_masks(self):
        """Structural masks of the A, B elements that depend on the aero parameters (seed 0
        Appendix A); :func:`lpv_sysid.models.quadrotor.linear.unknown_masks`."""
        return quadrotor_linear.unknown_masks(self)
