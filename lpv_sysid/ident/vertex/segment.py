"""The samples of one maneuver the vertex fit uses (seed 0 Sec. IV, Table 1): the trim
window and its mean, the excitation segment, the input the rotors act on (Eq. 8) and the
smoothed perturbations and derivatives over it (:mod:`lpv_sysid.ident.derivatives`)."""

from __future__ import annotations

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident import derivatives as deriv
from lpv_sysid.ident.vertex.config import IdentificationConfig
from lpv_sysid.ident.vertex.types import VertexData


def rotor_input(data: VertexData, params) -> np.ndarray:
    """The input the rotors act on: ``Mix clip(Mix^-1 u, 0, 1)`` (Eq. 8), unless given."""
    if data.u_eff is not None:
        return np.asarray(data.u_eff, dtype=float)
    from lpv_sysid.models.quadrotor import mixer

    mix = mixer(params.arm_length)
    return np.clip(np.asarray(data.u, dtype=float) @ np.linalg.inv(mix).T, 0.0, 1.0) @ mix.T


def _segment(t: np.ndarray, a: float, b: float, what: str, min_len: float) -> np.ndarray:
    idx = np.nonzero((t >= a) & (t < b))[0]
    if idx.size < 2 or (t[idx[-1]] - t[idx[0]]) < min_len:
        have = 0.0 if idx.size < 2 else t[idx[-1]] - t[idx[0]]
        raise ConfigError(
            f"{what}: segment [{a:.2f}, {b:.2f}) s has {have:.2f} s of data, "
            f"need at least {min_len:.2f} s"
        )
    return idx


def trim_window(trim: tuple[float, float], cfg: IdentificationConfig) -> tuple[float, float]:
    """Averaging window for x0, u0: the last ``trim_average`` s, at most half the trim segment."""
    a, b = trim
    return b - min(cfg.trim_average, 0.5 * (b - a)), b


def equilibrium(data: VertexData, cfg: IdentificationConfig) -> tuple[np.ndarray, np.ndarray]:
    """``x0, u0`` = means over the last ``trim_average`` seconds (at most half) of the trim
    segment (the vehicle may still be converging to the new reference at its start), seed 0
    Table 1.  This flown mean is *not* an equilibrium (the dynamics are nonlinear and the
    vehicle fluctuates about it); ``taylor2`` identification re-expands about the equilibrium."""
    a, b = trim_window(data.trim, cfg)
    idx = _segment(data.t, a, b, f"{data.name or 'vertex'} trim", min(0.5, b - a))
    return data.x[idx].mean(axis=0), data.u[idx].mean(axis=0)


def yaw_rate_samples(data: VertexData, cfg: IdentificationConfig) -> np.ndarray:
    """Per-sample yaw rate ``psi_dot = (sin(phi) q + cos(phi) r) / cos(theta)`` over the trim
    window (the equilibrium's yaw rate, not identified)."""
    a, b = trim_window(data.trim, cfg)
    idx = _segment(data.t, a, b, f"{data.name or 'vertex'} trim", min(0.5, b - a))
    x = np.asarray(data.x)[idx]
    return (np.sin(x[:, 0]) * x[:, 6] + np.cos(x[:, 0]) * x[:, 7]) / np.cos(x[:, 1])


def yaw_rate_mean(data: VertexData, cfg: IdentificationConfig) -> float:
    """The trim-window mean of the per-sample yaw rate (:func:`yaw_rate_samples`): the yaw rate
    of the equilibrium the model is re-expanded about. Not the yaw rate of the mean state: where
    the vehicle wobbles in the window (p, q far from 0, e.g. descending at 5 m/s) that one is
    several times the mean yaw rate (0.049 vs 0.017 rad/s on coverage airframe 12, seed 1), a
    bias :func:`yaw_rate_variance` cannot see."""
    return float(np.mean(yaw_rate_samples(data, cfg)))


def yaw_rate_variance(data: VertexData, cfg: IdentificationConfig, batches: int = 8) -> float:
    """Variance of :func:`yaw_rate_mean`: batch means over ``batches`` contiguous batches
    (robust to the samples' autocorrelation), ``var(batch means) / batches``."""
    psi = yaw_rate_samples(data, cfg)
    means = np.array([c.mean() for c in np.array_split(psi, batches) if c.size])
    return float(np.var(means, ddof=1) / means.size) if means.size > 1 else 0.0


def fit_indices(data: VertexData, cfg: IdentificationConfig):
    """``(dt, full, keep)``: sample indices differentiated (a little more than the fit segment,
    FFT-friendly) and the slice of them kept after cutting the smoother's edges."""
    t = np.asarray(data.t, dtype=float)
    dt = float(np.median(np.diff(t)))
    if not np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-9):
        raise ConfigError(f"{data.name or 'vertex'}: samples must be on a uniform grid")
    a, b = data.fit
    full = _segment(
        t, a, b, f"{data.name or 'vertex'} excitation", cfg.min_fit_duration + 2 * cfg.edge
    )
    if cfg.derivatives.method == "fourier":
        full = full[: deriv.fast_length(full.size)]  # FFT-friendly length, drops < 2 % (n > 2000)
    n_edge = int(round(cfg.edge / dt))
    return dt, full, slice(n_edge, full.size - n_edge)


def prepare(
    data: VertexData,
    cfg: IdentificationConfig,
    x0: np.ndarray,
    u0: np.ndarray,
    nonlinear=None,
    u: np.ndarray | None = None,
):
    """Smoothed perturbations and derivatives over the fit segment: ``(t, dxdot, dx, du)``.

    ``nonlinear(x_raw) -> (N, k)``: optional function of the *raw* states whose value is
    smoothed with the same filter and appended to the return tuple.  Nonlinear regressors
    must be computed before smoothing - ``L[r(x)]``, not ``r(L[x])`` - so that the filtered
    equation ``L[x'] = A L[x] + L[r(x)]`` still holds exactly.  ``u``: the input to use
    instead of ``data.u`` (e.g. after the ESC clip).
    """
    dt, full, keep = fit_indices(data, cfg)
    xs, xdot = deriv.smooth_and_differentiate(data.x[full], dt, cfg.derivatives)
    us = deriv.smooth((data.u if u is None else u)[full], dt, cfg.derivatives)
    out: tuple[np.ndarray, ...] = (
        np.asarray(data.t, dtype=float)[full][keep],
        xdot[keep],
        xs[keep] - x0,
        us[keep] - u0,
    )
    if nonlinear is not None:
        out = out + (deriv.smooth(nonlinear(data.x[full]), dt, cfg.derivatives)[keep],)
    return out
