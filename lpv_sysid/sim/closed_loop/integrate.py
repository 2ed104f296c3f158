"""Integration of seed 0 Eq. (33) on the signal grid.

``method="RK45"`` uses ``scipy.integrate.solve_ivp`` (Dormand-Prince, the
algorithm of Matlab's ode45 that the seed used), restarted on every sample interval so the
kinks of the interpolated signals are step boundaries (one call over the whole horizon
straddles them and loses ~4 digits); ``method="rk4"`` is a fixed-step classical Runge-Kutta on the
signal grid, with each sample interval split into enough sub-steps that
``h * max|eig(A + B K)| <= rk4_lambda_h`` (RK4's stability region reaches 2.78 on the real axis;
the default 0.5 keeps the error small). Both report the solution on the signal grid.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.integrate import solve_ivp

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import SafetyError
from lpv_sysid.sim.closed_loop.references import ReferenceSignals
from lpv_sysid.sim.closed_loop.schedule import ScheduledModel


@dataclass(frozen=True)
class ClosedLoopConfig:
    """How Eq. (33) is integrated (see module docstring)."""

    kappa: float = cf.number(1.0, "excitation scale (Eq. 33: kappa u_e)", lo=0.0, lo_open=True)
    method: str = cf.choice("RK45", ("RK45", "rk4"), "adaptive RK45 or fixed-step RK4")
    rtol: float = cf.number(1e-7, "RK45 relative tolerance", lo=0.0, lo_open=True, hi=1.0)
    atol: float = cf.number(1e-9, "RK45 absolute tolerance", lo=0.0, lo_open=True)
    rk4_lambda_h: float = cf.number(
        0.5,
        "RK4 step times the fastest closed-loop eigenvalue (RK4 is stable up to 2.78)",
        lo=0.0,
        lo_open=True,
        hi=2.78,
    )
    divergence_bound: float = cf.number(
        1e6,
        "a state above this magnitude marks the run as diverged (finiteness always checked)",
        lo=0.0,
        lo_open=True,
    )

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "closed_loop")


def closed_loop_rate(model: ScheduledModel, signals: ReferenceSignals) -> float:
    """max |eig(A + B K)| over the signal's scheduling samples (for the RK4 sub-step)."""
    idx = np.unique(np.linspace(0, signals.t.size - 1, min(signals.t.size, 25)).astype(int))
    rate = 0.0
    for k in idx:
        vd = signals.v_d[k]
        acl = model.A(vd) + model.B(vd) @ model.K(vd)
        rate = max(rate, float(np.max(np.abs(np.linalg.eigvals(acl)))))
    return rate


def rk4_on_grid(
    f: Callable[[float, np.ndarray, int], np.ndarray],
    t: np.ndarray,
    x_init: np.ndarray,
    n_sub: int,
    bound: float,
) -> tuple[np.ndarray, int]:
    """Classical RK4 on grid t with n_sub equal sub-steps per interval (results on t)."""
    x = np.empty((t.size, x_init.size))
    x[0] = x_init
    xi = x_init.copy()
    steps = 0
    for k in range(t.size - 1):
        h = (t[k + 1] - t[k]) / n_sub
        tk = t[k]
        for j in range(n_sub):
            ts = tk + j * h
            # all stages inside FOH segment k (its slope dv_d/dt holds up to t[k+1])
            k1 = f(ts, xi, k)
            k2 = f(ts + 0.5 * h, xi + 0.5 * h * k1, k)
            k3 = f(ts + 0.5 * h, xi + 0.5 * h * k2, k)
            k4 = f(ts + h, xi + h * k3, k)
            xi = xi + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            steps += 4
        if not np.all(np.isfinite(xi)) or np.max(np.abs(xi)) > bound:
            x[k + 1 :] = np.nan
            raise Diverged(t[k + 1], x, steps)
        x[k + 1] = xi
    return x, steps


def rk45_segments(
    f: Callable[..., np.ndarray], t: np.ndarray, x_init: np.ndarray, config: ClosedLoopConfig
) -> tuple[np.ndarray, int]:
    """solve_ivp RK45 (ode45's Dormand-Prince pair) restarted on every FOH interval.

    The right-hand side has a kink at every sample (slope of the interpolated signals), which
    an embedded error estimator straddling it handles poorly; restarting makes every kink a
    step boundary. The last accepted step size seeds the next interval.
    """
    x = np.empty((t.size, x_init.size))
    x[0] = x_init
    xi = x_init
    nfev = 0
    h = None
    for k in range(t.size - 1):
        sol = solve_ivp(
            f,
            (t[k], t[k + 1]),
            xi,
            method="RK45",
            args=(k,),
            rtol=config.rtol,
            atol=config.atol,
            first_step=h,
        )
        nfev += int(sol.nfev)
        if sol.status != 0 or not np.all(np.isfinite(sol.y[:, -1])):
            raise SafetyError(f"Eq. (33) integration failed at t={t[k]:.3f} s: {sol.message}")
        xi = sol.y[:, -1]
        if np.max(np.abs(xi)) > config.divergence_bound:
            raise SafetyError(
                f"Eq. (33) closed loop diverged at t={t[k + 1]:.3f} s "
                f"(|x| > {config.divergence_bound:g})"
            )
        if sol.t.size > 1 and k + 2 < t.size:
            h = min(2.0 * float(sol.t[-1] - sol.t[-2]), float(t[k + 2] - t[k + 1]))
        x[k + 1] = xi
    return x, nfev


class Diverged(Exception):
    def __init__(self, t_fail: float, x: np.ndarray, steps: int) -> None:
        super().__init__(t_fail)
        self.t_fail, self.x, self.steps = t_fail, x, steps
