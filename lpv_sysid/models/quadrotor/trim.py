"""Equilibria of the seed 0 quadrotor (seed 0 Sec. III): v = v_d, constant Euler angles,
Omega = Omega_0, solved inside the rotor-speed limits."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lpv_sysid.errors import SolverError
from lpv_sysid.models.quadrotor.params import as_finite
from lpv_sysid.models.quadrotor.protocol import QuadrotorModel
from lpv_sysid.models.quadrotor.states import reduced_state


@dataclass(frozen=True)
class Trim:
    """Equilibrium of seed 0 Sec. III: v = v_d, constant Euler angles, Omega = Omega_0."""

    v_d: np.ndarray  # (3,) commanded body velocity, FRD, m/s
    yaw_rate: float  # psi-dot, rad/s
    x0: np.ndarray  # (12,) STATE_NAMES
    u0: np.ndarray  # (4,) INPUT_NAMES
    full_state: np.ndarray  # (16,) FULL_STATE_NAMES (position 0, psi 0)
    residual: float  # max |xdot| of phi, theta, v, omega, Omega at the solution


def trim(model: QuadrotorModel, v_body, yaw_rate: float = 0.0) -> Trim:
    """Equilibrium for body velocity v_d and yaw rate psi-dot (seed 0 Sec. III).

    Solves v-dot = 0, omega-dot = 0 for (phi_0, theta_0, Omega_0) with
    ``scipy.optimize.least_squares`` inside the rotor-speed limits; Omega-dot = 0 fixes
    u_ESC,0 = a Omega_0 / b and u_0 = Mix u_ESC,0. Raises SolverError when no trim exists.
    """
    v_d = as_finite("trim.v_body", v_body, (3,))
    if not math.isfinite(yaw_rate):
        raise SolverError("trim: yaw_rate is not finite")
    p = model.params
    om_h = math.sqrt(p.mass * p.g / max(-p.K["z_T0"], 1e-12))
    x0g = np.array([0.0, 0.0, om_h, om_h, om_h, om_h])
    lo = np.array([-1.2, -1.2] + [p.omega_min] * 4)
    hi = np.array([1.2, 1.2] + [p.omega_max] * 4)
    x0g[2:] = np.clip(x0g[2:], p.omega_min + 1.0, p.omega_max - 1.0)

    def body_rates(phi, th):
        # Eq. (2) inverted for Euler rates (0, 0, psi-dot)
        return (
            -math.sin(th) * yaw_rate,
            math.sin(phi) * math.cos(th) * yaw_rate,
            math.cos(phi) * math.cos(th) * yaw_rate,
        )

    def resid(z):
        w = body_rates(z[0], z[1])
        x = [0.0, 0.0, 0.0, z[0], z[1], 0.0, *v_d.tolist(), *w, *z[2:].tolist()]
        xd = model.derivatives_list(x, (model.mix @ (p.a_omega * z[2:] / p.b_omega)).tolist())
        return np.array(xd[6:12]) * np.array([1, 1, 1, 50, 50, 50])

    from scipy import optimize  # here: scipy.optimize costs ~0.1 s to import

    try:
        sol = optimize.least_squares(
            resid,
            x0g,
            bounds=(lo, hi),
            x_scale=np.r_[0.1, 0.1, [100.0] * 4],
            xtol=1e-14,
            ftol=1e-14,
            gtol=1e-14,
            max_nfev=2000,
        )
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise SolverError(f"trim v_d={v_d.tolist()}: solver failed ({exc})") from None
    res = float(np.max(np.abs(resid(sol.x))))
    if not np.isfinite(res) or res > 1e-6:
        raise SolverError(
            f"trim v_d={v_d.tolist()} yaw_rate={yaw_rate}: no equilibrium inside the rotor "
            f"limits [{p.omega_min}, {p.omega_max}] rad/s (residual {res:.3g}, "
            f"Omega={np.round(sol.x[2:], 1).tolist()})"
        )
    phi, th = float(sol.x[0]), float(sol.x[1])
    Om = sol.x[2:].copy()
    u_esc = p.a_omega * Om / p.b_omega
    if np.any(u_esc > 1.0) or np.any(Om >= p.omega_max - 1e-6) or np.any(Om <= p.omega_min + 1e-6):
        raise SolverError(
            f"trim v_d={v_d.tolist()}: equilibrium needs rotor speeds "
            f"{np.round(Om, 1).tolist()} at the limits [{p.omega_min}, {p.omega_max}] rad/s"
        )
    w = body_rates(phi, th)
    x16 = np.array([0, 0, 0, phi, th, 0.0, *v_d, *w, *Om])
    controller_state = reduced_state(x16, p.arm_length)
    u0 = model.mix @ u_esc
    resid_max = float(
        np.max(np.abs(model.derivatives(x16, u0)[[3, 4, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15]]))
    )
    return Trim(
        v_d=v_d.copy(),
        yaw_rate=float(yaw_rate),
        x0=controller_state,
        u0=u0,
        full_state=x16,
        residual=resid_max,
    )
