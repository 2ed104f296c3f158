"""What the nonlinear identification of :mod:`lpv_sysid.ident.nonlinear` fits: the regressors
of seed 0 Eq. (6) per axis, the measured generalised force of Eqs. (3c)-(3d) and the flight
record both are computed from, and the result types of its two steps."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lpv_sysid.errors import ConfigError

AXES = ("X", "Y", "Z", "L", "M", "N")
#: (K name, regressor label) per axis of Eq. (6); K names are ``models.quadrotor.K_NAMES``
REGRESSORS = {
    "X": (("x_mu0", "u"), ("x_muw", "u w"), ("x_muh", "u dt")),
    "Y": (("y_mu0", "v"), ("y_muw", "v w"), ("y_muh", "v dt")),
    "Z": (
        ("z_T0", "dt^2"),
        ("z_mu0", "dt"),
        ("z_mu", "u^2+v^2"),
        ("z_muw", "4w dt - p da - q de"),
    ),
    "L": (
        ("l_T0", "da^2"),
        ("l_mu0", "da"),
        ("l_muw", "w da - 2l^2 p dt - l^2 q dr/2"),
        ("l_muh", "v dt"),
        ("l_muh_mu0", "v"),
        ("l_muh_muw", "v w"),
        ("l_dr", "u dr"),
    ),
    "M": (
        ("m_T0", "de^2"),
        ("m_mu0", "de"),
        ("m_muw", "w de - 2l^2 q dt - l^2 p dr/2"),
        ("m_muh", "u dt"),
        ("m_muh_mu0", "u"),
        ("m_muh_muw", "u w"),
        ("m_dr", "v dr"),
    ),
    "N": (
        ("n_Q0", "dr^2"),
        ("n_mu0", "dr"),
        ("n_muw", "w dr + p de + q da"),
        ("n_muw2", "p q"),
        ("n_muh", "u da + v de"),
        ("n_muh_muw", "u p + v q"),
    ),
}


@dataclass(frozen=True)
class FlightData:
    """Aligned measurements on a uniform grid (NED/FRD, SI)."""

    t: np.ndarray  # (N,)
    euler: np.ndarray  # (N, 2) phi, theta (psi does not enter Eq. 3c-3d)
    v: np.ndarray  # (N, 3) body velocity
    omega: np.ndarray  # (N, 3) body rates
    Omega: np.ndarray  # (N, 4) rotor speeds
    v_dot: np.ndarray  # (N, 3)
    omega_dot: np.ndarray  # (N, 3)
    Omega_dot: np.ndarray  # (N, 4)


def regressors_of_delta(v, omega, delta, delta_sq, arm_length: float) -> dict[str, np.ndarray]:
    """Regressor matrices (N, n_axis) of Eq. (6a)-(6f) in the order of :data:`REGRESSORS`,
    from body velocity ``v`` (N, 3), body rates ``omega`` (N, 3) and the virtual actuators of
    Eq. (7), ``delta = Mix Omega`` and ``delta_sq = Mix Omega^2`` (N, 4 each; ``dt^2`` is the
    first entry of ``Mix Omega^2``, not ``dt`` squared). The one implementation of Eq. (6)'s
    regressors: the identification and the correlation of Fig. 10 both use it.

    >>> import numpy as np
    >>> r = regressors_of_delta(np.array([[1.0, 2.0, 3.0]]), np.zeros((1, 3)),
    ...                         np.array([[4.0, 0, 0, 0]]), np.array([[16.0, 0, 0, 0]]), 0.25)
    >>> r["X"].tolist()  # u, u w, u dt
    [[1.0, 3.0, 4.0]]
    >>> r["Z"].tolist()  # dt^2, dt, u^2 + v^2, 4 w dt - p da - q de
    [[16.0, 4.0, 5.0, 48.0]]
    """
    v = np.atleast_2d(v)
    omega = np.atleast_2d(omega)
    u, vv, w = v[:, 0], v[:, 1], v[:, 2]
    p, q = omega[:, 0], omega[:, 1]  # the regressors of Eq. (6) do not use r
    d = np.atleast_2d(delta)
    d2 = np.atleast_2d(delta_sq)
    dt, da, de, dr = d.T
    l2 = arm_length**2
    return {
        "X": np.stack([u, u * w, u * dt], axis=1),
        "Y": np.stack([vv, vv * w, vv * dt], axis=1),
        "Z": np.stack([d2[:, 0], dt, u * u + vv * vv, 4 * w * dt - p * da - q * de], axis=1),
        "L": np.stack(
            [
                d2[:, 1],
                da,
                w * da - 2 * l2 * p * dt - 0.5 * l2 * q * dr,
                vv * dt,
                vv,
                vv * w,
                u * dr,
            ],
            axis=1,
        ),
        "M": np.stack(
            [
                d2[:, 2],
                de,
                w * de - 2 * l2 * q * dt - 0.5 * l2 * p * dr,
                u * dt,
                u,
                u * w,
                vv * dr,
            ],
            axis=1,
        ),
        "N": np.stack(
            [d2[:, 3], dr, w * dr + p * de + q * da, p * q, u * da + vv * de, u * p + vv * q],
            axis=1,
        ),
    }


def regressors(
    v, omega, Omega, Omega_dot, arm_length: float, mix: np.ndarray
) -> dict[str, np.ndarray]:
    """:func:`regressors_of_delta` from rotor speeds ``Omega`` (N, 4) through the mixer
    ``mix`` of Eq. (7) (``Omega_dot`` is not used by the regressors of Eq. 6)."""
    delta, delta_sq = virtual_actuators(np.atleast_2d(Omega), mix)
    return regressors_of_delta(v, omega, delta, delta_sq, arm_length)


def gravity_body(phi, th, g):
    """g R_IB^T e3 (Eq. 3c) for arrays of roll/pitch."""
    return g * np.stack([-np.sin(th), np.sin(phi) * np.cos(th), np.cos(phi) * np.cos(th)], axis=-1)


def generalized_force(data: FlightData, params, smoother=None) -> tuple[np.ndarray, np.ndarray]:
    """Measured F (N, 3) and M (N, 3) from Eqs. (3c)-(3d) (nonlinear terms smoothed by
    ``smoother`` when given, see :func:`regression`)."""
    m, g = params.mass, params.g
    inertia = np.asarray(params.inertia, dtype=float)
    sm = smoother or (lambda a: a)
    known_v = sm(
        np.cross(data.v, data.omega) + gravity_body(data.euler[:, 0], data.euler[:, 1], g)
    )
    F = m * (data.v_dot - known_v)
    M = data.omega_dot @ inertia.T - sm(np.cross(data.omega @ inertia.T, data.omega))
    return F, M


def flight_data(
    t: np.ndarray,
    euler: np.ndarray,
    v: np.ndarray,
    omega: np.ndarray,
    Omega: np.ndarray,
    deriv_cfg=None,
    edge_s: float = 0.5,
):
    """Measured arrays on a uniform grid -> ``(FlightData, smoother, keep)`` for
    :func:`regression`.

    Derivatives of ``v``, ``omega``, ``Omega`` by the global Fourier (or Savitzky-Golay)
    differentiator of :mod:`lpv_sysid.ident.derivatives`; the states stay raw (the smoother
    is applied to the nonlinear terms inside :func:`regression`); ``keep`` drops ``edge_s``
    at both ends.
    """
    from lpv_sysid.ident import derivatives as dv

    cfg = deriv_cfg or dv.DerivativeConfig()
    t = np.asarray(t, dtype=float)
    dt = float(t[1] - t[0])
    n_edge = int(round(edge_s / dt))
    if t.size <= 2 * n_edge + 10:
        raise ConfigError(f"flight record of {t.size} samples is too short (edges {n_edge} each)")
    _, v_dot = dv.smooth_and_differentiate(v, dt, cfg)
    _, w_dot = dv.smooth_and_differentiate(omega, dt, cfg)
    _, O_dot = dv.smooth_and_differentiate(Omega, dt, cfg)
    data = FlightData(
        t,
        np.asarray(euler)[:, :2],
        np.asarray(v),
        np.asarray(omega),
        np.asarray(Omega),
        v_dot,
        w_dot,
        O_dot,
    )
    return data, (lambda a: dv.smooth(a, dt, cfg)), slice(n_edge, t.size - n_edge)


@dataclass
class AxisFit:
    axis: str
    names: tuple[str, ...]
    labels: tuple[str, ...]
    K: np.ndarray
    std: np.ndarray
    r2: float
    correlation: np.ndarray


@dataclass
class NonlinearResult:
    K: dict[str, float]
    std: dict[str, float]
    axes: dict[str, AxisFit]
    method: str = "regression"
    cost: float | None = None
    refined_std: dict[str, float] = field(default_factory=dict)


def _check(data: FlightData) -> int:
    n = np.asarray(data.t).size
    for name in ("euler", "v", "omega", "Omega", "v_dot", "omega_dot", "Omega_dot"):
        a = np.asarray(getattr(data, name))
        if a.shape[0] != n:
            raise ConfigError(f"flight data '{name}' has {a.shape[0]} samples, t has {n}")
        if not np.all(np.isfinite(a)):
            raise ConfigError(f"flight data '{name}' contains NaN/inf")
    return n


def virtual_actuators(Omega: np.ndarray, mix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(delta, delta^2) of seed 0 Eq. (7) from rotor speeds Omega (N, 4)."""
    Omega = np.asarray(Omega, dtype=float)
    mix = np.asarray(mix, dtype=float)
    return Omega @ mix.T, (Omega * Omega) @ mix.T
