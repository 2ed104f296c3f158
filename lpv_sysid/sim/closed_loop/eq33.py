"""The closed loop of seed 0 Eq. (33) (:func:`simulate_eq33`, :func:`eq33_rhs`) with its
performance output and the Eq. (34) equilibrium rate; the method is the
:mod:`lpv_sysid.sim.closed_loop` docstring."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.sim.closed_loop.fused import fused_eq33
from lpv_sysid.sim.closed_loop.integrate import (
    ClosedLoopConfig,
    Diverged,
    closed_loop_rate,
    rk4_on_grid,
    rk45_segments,
)
from lpv_sysid.sim.closed_loop.laws import ControlLaw, linear_lpv_law
from lpv_sysid.sim.closed_loop.references import ReferenceSignals
from lpv_sysid.sim.closed_loop.schedule import LastPointCache, ScheduledModel

log = logging.getLogger(__name__)

#: indices of the body velocity ``u, v, w`` in the 12-state of DESIGN.md (seed 0 Eq. 14).
VELOCITY_INDEX = (2, 3, 4)


def performance_matrix(
    Q: np.ndarray, n_x: int, velocity_index: Sequence[int] = VELOCITY_INDEX
) -> np.ndarray:
    """C of Eq. (19b): z = Q^-1 dv = C dx (Eq. 18)."""
    Q = np.asarray(Q, dtype=float)
    S = np.zeros((len(velocity_index), n_x))
    S[np.arange(len(velocity_index)), list(velocity_index)] = 1.0
    return np.linalg.solve(Q, S)


def x0_dot(model: ScheduledModel, v_d: np.ndarray, v_d_dot: np.ndarray) -> np.ndarray:
    """Equilibrium state rate of seed 0 Eq. (34): x0' = (dx0/dv_d) (dv_d/dt)."""
    return np.asarray(model.dx0_dvd(v_d), dtype=float) @ np.asarray(v_d_dot, dtype=float)


def eq33_rhs(
    t: float,
    x: np.ndarray,
    model: ScheduledModel,
    signals: ReferenceSignals,
    law: ControlLaw,
    kappa: float,
    segment: Optional[int] = None,
    moving_equilibrium: bool = True,
) -> np.ndarray:
    """Right-hand side of seed 0 Eq. (33); the command u of ``law`` includes R kappa u_e.

    ``moving_equilibrium=False`` drops the ``x0'`` term (module docstring: the linear model of
    the real vehicle, used with :func:`feedforward_law`)."""
    v_d, v_d_dot, ue = signals.at(t, segment)
    u = law(t, x, v_d, kappa * ue)
    xdot = model.A(v_d) @ (x - model.x0(v_d)) + model.B(v_d) @ (u - model.u0(v_d))
    if moving_equilibrium:
        xdot = xdot + x0_dot(model, v_d, v_d_dot)
    return xdot


def l2_norm(t: np.ndarray, y: np.ndarray) -> float:
    """sqrt(int y^T y dt) by the trapezoidal rule on grid t (Eq. 26 / Eq. 29 norm)."""
    y = np.asarray(y, dtype=float).reshape(len(t), -1)
    return float(np.sqrt(np.trapz(np.sum(y * y, axis=1), t)))


@dataclass
class ClosedLoopResult:
    """Time histories on the signal grid and the achieved L2 gain (seed 0 Eq. 29)."""

    t: np.ndarray
    x: np.ndarray  # (N, n_x) absolute state
    dx: np.ndarray  # (N, n_x) x - x0(v_d)
    v_d: np.ndarray  # (N, 3)
    ue: np.ndarray  # (N, n_e) kappa u_e actually applied
    u: np.ndarray  # (N, n_u) total virtual command
    z: np.ndarray  # (N, 3) Q^-1 (v - v_d), Eq. (18)
    z_model: np.ndarray  # (N, 3) C dx, Eq. (19b)
    tracking_error: np.ndarray  # (N, 3) v - v_d (Fig. 9)
    z_norm: float
    ue_norm: float
    gain: float  # ||z||_2 / ||kappa u_e||_2
    gain_model: float  # ||C dx||_2 / ||kappa u_e||_2
    gamma: Optional[float]
    kappa: float
    method: str
    n_steps: int = 0  # right-hand-side evaluations
    info: dict = field(default_factory=dict)

    @property
    def within_gamma(self) -> Optional[bool]:
        return None if self.gamma is None else bool(self.gain <= self.gamma)


def simulate_eq33(
    model: ScheduledModel,
    signals: ReferenceSignals,
    R: np.ndarray,
    Q: np.ndarray,
    gamma: Optional[float] = None,
    config: ClosedLoopConfig = ClosedLoopConfig(),
    x_init: Optional[np.ndarray] = None,
    law: Optional[ControlLaw] = None,
    velocity_index: Sequence[int] = VELOCITY_INDEX,
    moving_equilibrium: bool = True,
) -> ClosedLoopResult:
    """Simulate seed 0 Eq. (33) over the signal grid.

    ``x_init`` defaults to the equilibrium ``x0(v_d(0))`` (so dx(0) = 0 and the L2 gain of
    Eq. (29) is the gain from zero initial conditions). ``law`` defaults to
    :func:`linear_lpv_law` (the unsaturated Eq. 31 law used for the certificate).
    Raises :class:`SafetyError` when the state becomes non-finite or exceeds
    ``config.divergence_bound``. ``moving_equilibrium=False`` drops the ``x0'`` term of Eq. (33)
    (module docstring; pair it with :func:`feedforward_law`).
    """
    R = np.asarray(R, dtype=float)
    model = LastPointCache(model)
    v0 = signals.v_d[0]
    x_start = (
        np.asarray(model.x0(v0), dtype=float)
        if x_init is None
        else np.asarray(x_init, dtype=float)
    )
    n_x = x_start.size
    if R.shape != (np.asarray(model.B(v0)).shape[1], signals.u_e.shape[1]):
        raise ConfigError(
            f"R has shape {R.shape}, expected ({np.asarray(model.B(v0)).shape[1]}, "
            f"{signals.u_e.shape[1]}) (inputs x excitation channels)"
        )
    kappa = config.kappa
    fused = fused_eq33(model, signals, law, R, kappa, moving_equilibrium)
    law = law or linear_lpv_law(model, R)

    def generic(t: float, x: np.ndarray, segment: Optional[int] = None) -> np.ndarray:
        return eq33_rhs(t, x, model, signals, law, kappa, segment, moving_equilibrium)

    f: Callable[[float, np.ndarray, Optional[int]], np.ndarray] = (
        fused if fused is not None else generic
    )

    t = signals.t
    info: dict = {}
    if config.method == "RK45":
        x, n_steps = rk45_segments(f, t, x_start, config)
        info["nfev"] = n_steps
    else:
        rate = closed_loop_rate(model, signals)
        n_sub = max(1, int(np.ceil(signals.dt * rate / config.rk4_lambda_h)))
        info["rk4_substeps"] = n_sub
        info["maxclosed_loop_rate"] = rate
        try:
            x, n_steps = rk4_on_grid(f, t, x_start, n_sub, config.divergence_bound)
        except Diverged as exc:
            raise SafetyError(
                f"Eq. (33) closed loop diverged at t={exc.t_fail:.3f} s "
                f"(non-finite state or |x| > {config.divergence_bound:g})"
            ) from None
    if np.max(np.abs(x)) > config.divergence_bound:
        raise SafetyError(f"Eq. (33) closed loop diverged (|x| > {config.divergence_bound:g})")

    # Post-process on the grid (exact FOH samples).
    C = performance_matrix(Q, n_x, velocity_index)
    vi = list(velocity_index)
    ue = kappa * signals.u_e
    if fused is not None:
        x0s = np.array([fused.at(vd)[3] for vd in signals.v_d.tolist()])
        u = np.array(
            [fused.law(tk, xk, vd, uek) for tk, xk, vd, uek in zip(t, x, signals.v_d, ue)]
        )
    else:
        x0s = np.array([model.x0(vd) for vd in signals.v_d])
        u = np.array([law(tk, xk, vd, uek) for tk, xk, vd, uek in zip(t, x, signals.v_d, ue)])
    dx = x - x0s
    z_model = dx @ C.T
    err = x[:, vi] - signals.v_d
    z = np.linalg.solve(np.asarray(Q, dtype=float), err.T).T
    z_norm = l2_norm(t, z)
    ue_norm = l2_norm(t, ue)
    if ue_norm <= 0:
        raise ConfigError(
            "signals: the excitation u_e is identically zero, the L2 gain is undefined"
        )
    return ClosedLoopResult(
        t=t,
        x=x,
        dx=dx,
        v_d=signals.v_d,
        ue=ue,
        u=u,
        z=z,
        z_model=z_model,
        tracking_error=err,
        z_norm=z_norm,
        ue_norm=ue_norm,
        gain=z_norm / ue_norm,
        gain_model=l2_norm(t, z_model) / ue_norm,
        gamma=gamma,
        kappa=kappa,
        method=config.method,
        n_steps=n_steps,
        info={**info, "moving_equilibrium": bool(moving_equilibrium)},
    )
