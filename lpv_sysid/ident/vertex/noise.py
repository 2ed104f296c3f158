"""Errors in variables of the vertex regressions: the measurement-noise variance of the
smoothed states and their derivatives (``identification.measurement_noise``) and, per
regressor column, the variance the equation-error solver compensates
(:mod:`lpv_sysid.ident.equation_error`)."""

from __future__ import annotations

import numpy as np

from lpv_sysid.ident import derivatives as deriv
from lpv_sysid.ident.vertex.config import IdentificationConfig
from lpv_sysid.models.quadrotor import STATE_NAMES


def regressor_noise_var(
    cfg: IdentificationConfig, params, dt: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """Errors-in-variables input: ``(var (12,), var of d/dt (12,), rotor-speed var)`` of the
    *smoothed* measured states (white noise of std ``s`` sampled at ``r`` Hz has the one-sided
    density ``2 s^2 / r``; the smoother passes ``int L(f)^2 df``, the differentiator
    ``int (2 pi f)^2 L(f)^2 df``; ``delta = Mix Omega`` when only the rotor noise is given)."""
    from lpv_sysid.models.quadrotor import mixer

    f = np.linspace(0.0, 0.5 / dt, 4001)
    if cfg.derivatives.method == "fourier":
        L2 = deriv.fourier_gain(f, cfg.derivatives.f_cut, cfg.derivatives.taper) ** 2
    else:
        w = deriv._savgol_window(cfg.derivatives.window_s, dt, cfg.derivatives.polyorder, 10**6)
        L2 = deriv.savgol_gain(f, dt, w, cfg.derivatives.polyorder, deriv=0) ** 2
    g0 = float(np.trapz(L2, f))
    g1 = float(np.trapz((2 * np.pi * f) ** 2 * L2, f))
    var, dvar = np.zeros(12), np.zeros(12)
    noise = cfg.measurement_noise
    rotor = 0.0
    if "rotor" in noise:
        s, r = noise["rotor"]
        rotor = 2 * s**2 / (r or 1.0 / dt)
        mix = mixer(params.arm_length)
        var[8:12] = rotor * g0 * np.sum(mix**2, axis=1)
        dvar[8:12] = rotor * g1 * np.sum(mix**2, axis=1)
    for k, (s, r) in noise.items():
        if k != "rotor":
            j = STATE_NAMES.index(k)
            dens = 2 * s**2 / (r or 1.0 / dt)
            var[j], dvar[j] = dens * g0, dens * g1
    return var, dvar, rotor * g0


def design_noise(labels, var: np.ndarray, dvar: np.ndarray) -> np.ndarray | None:
    """Per regressor column its measurement-error variance: ``x<j>`` the smoothed state's, ``aux``
    the rotor acceleration's (d delta_r / dt); commands, intercepts and the second-order
    nuisance columns are taken as exact (their noise enters only at second order)."""
    out = np.zeros(len(labels))
    for k, lab in enumerate(labels):
        if lab.startswith("x"):
            out[k] = var[int(lab[1:])]
        elif lab == "aux":
            out[k] = dvar[11]
    return out if np.any(out > 0) else None
