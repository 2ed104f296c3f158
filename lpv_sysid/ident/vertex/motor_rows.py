"""The motor rows of the vertex identification: the rotor-speed model Eq. (8) of seed 0,
``Omega' = -a_Omega (Omega - Omega_0) + b_Omega (e - e_0)``, as one stacked equation-error
design (:class:`lpv_sysid.ident.equation_error.RowDesign`), gated while a rotor is pinned at
a speed limit and with the command-to-rotor latency (:func:`motor_design`); the motor model's
own response (:func:`pinned`, :func:`motor_response`) for the gate and the instruments."""

from __future__ import annotations

import numpy as np

from lpv_sysid.ident import derivatives as deriv
from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident.vertex.config import IdentificationConfig
from lpv_sysid.ident.vertex.types import VertexData


def pinned(
    e: np.ndarray,
    Om_start: np.ndarray,
    dt: float,
    params,
    a: float | None = None,
    b: float | None = None,
    speeds: bool = False,
):
    """(N, 4) fraction of the interval ``[t_k - dt/2, t_k + dt/2)`` during which rotor i is
    held at a speed limit, where Eq. (8) does not hold (the speed is clamped).

    Decided on the motor model's noise-free response to the command ``e`` (held over each
    interval), not on the noisy telemetry (a rotor decelerating through a noise band above
    ``omega_min`` would be taken as pinned), and exactly within an interval: with ``e`` held,
    ``Omega(t) = Omega_inf + (Omega_s - Omega_inf) exp(-a t)``, ``Omega_inf = b e / a``, reaches a
    limit after ``ln((Omega_s - Omega_inf) / (limit - Omega_inf)) / a``; a pinned rotor is released
    as soon as ``Omega_inf`` is back inside the limits.  The fraction, not a 0/1 flag per sample,
    keeps the gated regressors free of the half-sample bias at every entry into the pin.
    ``speeds``: also return the model's rotor speeds at the sample times (N, 4), the noise-free
    instrument of the motor regression.
    """
    import math

    a = params.a_omega if a is None else a
    b = params.b_omega if b is None else b
    lo, hi = params.omega_min, params.omega_max
    ad = math.exp(-a * dt)
    E = np.asarray(e, dtype=float)
    out = np.zeros(E.shape)
    start = np.zeros(E.shape)  # model speed at each interval start
    for i in range(E.shape[1]):
        Om = min(max(float(Om_start[i]), lo), hi)
        col = E[:, i].tolist()
        frac = [0.0] * len(col)  # plain floats in the loop, one copy into the arrays after it
        st = [0.0] * len(col)
        for k, ek in enumerate(col):
            st[k] = Om
            inf = b * ek / a
            if (Om <= lo and inf <= lo) or (Om >= hi and inf >= hi):
                frac[k] = 1.0  # pinned through the interval
                continue
            nxt = inf + (Om - inf) * ad
            if nxt < lo or nxt > hi:  # reaches the limit inside the interval
                lim = lo if nxt < lo else hi
                t_hit = math.log((Om - inf) / (lim - inf)) / a
                frac[k] = max(0.0, 1.0 - t_hit / dt)
                Om = lim
            else:
                Om = nxt
        out[:, i] = frac
        start[:, i] = st
    if not speeds:
        return out
    mid = 0.5 * (start + np.vstack([start[1:], start[-1:]]))  # at t_k, mid-interval
    return out, mid


def motor_response(u: np.ndarray, delta_start: np.ndarray, dt: float, params) -> np.ndarray:
    """Virtual actuators of the motor model Eq. (8), ``delta' = -a_Omega delta + b_Omega u``,
    driven by ``u`` (N, 4) from ``delta_start`` (exact for an input held over each step)."""
    from scipy.signal import lfilter

    ad = np.exp(-params.a_omega * dt)
    g = (1.0 - ad) * params.b_omega / params.a_omega
    u = np.asarray(u, dtype=float)
    zi = np.asarray(delta_start, dtype=float)[None, :]
    return lfilter([0.0, g], [1.0, -ad], u, axis=0, zi=zi)[0]


def _stacked(
    x: np.ndarray, dt: float, cfg: IdentificationConfig, keep, derivative: bool = False
) -> np.ndarray:
    """The four rotors' columns of ``x`` (N, 4) smoothed (``derivative``: differentiated), cut
    to ``keep`` and stacked rotor after rotor (:func:`lpv_sysid.ident.derivatives.smooth_columns`:
    each column exactly as filtered alone)."""
    return deriv.smooth_columns(x, dt, cfg.derivatives, derivative)[keep].T.reshape(-1)


def motor_design(
    data: VertexData,
    cfg: IdentificationConfig,
    params,
    full,
    keep,
    x0,
    u0,
    u_in: np.ndarray,
    max_delay: float = 0.05,
    rotor_var: float = 0.0,
):
    """The motor model Eq. (8) per rotor, ``Omega_i' = g_i(t) [theta_a (Omega_i - Omega_i0)
    + theta_b (e_i(t - tau) - e_i0) + c_i]`` with ``e = Mix^-1 u`` after the ESC clip, stacked
    over the four rotors (one ``theta_a = -a_Omega``, ``theta_b = b_Omega``, seed 0 Eq. 15).

    ``g_i = 0`` while rotor i is :func:`pinned` at a speed limit (there ``Omega_i' = 0``): the
    gated regressors are formed *before* smoothing, so the filtered equation holds at every
    sample and nothing has to be cut out.  ``c_i`` absorbs the offset of the flown mean from
    rest; ``tau`` is the command-to-rotor latency (ESC, telemetry, command hold; with
    ``a_Omega ~ 12 /s`` 0.1 ms already biases ``a, b`` by ~0.1 %, more than their standard
    error on a 30 s record), found by Gauss-Newton (the regressor of a latency increment is
    ``-b g e'``) and kept as the column ``delay`` (increment ~ 0 at convergence) so that its
    uncertainty enters the covariance.  ``rotor_var``: variance of the smoothed rotor-speed
    telemetry noise (errors in variables of the ``a`` column, bias-compensated in the latency
    search too).  Returns ``(RowDesign with stack=4, tau)`` or ``(None, reason)`` when the data
    do not allow it.
    """
    from scipy.interpolate import CubicSpline

    from lpv_sysid.models.quadrotor import mixer

    if cfg.motor == "known":
        return None, "configured as known"
    if not data.motor_identifiable:
        return None, "rotor speeds not measured independently of the command"
    dt = float(np.median(np.diff(data.t)))
    mi = np.linalg.inv(mixer(params.arm_length))
    Om = np.asarray(data.x, dtype=float)[full, 8:12] @ mi.T
    e = np.asarray(u_in, dtype=float)[full] @ mi.T
    Om0, e0 = mi @ x0[8:12], mi @ u0
    t = np.asarray(data.t, dtype=float)[full]
    spline = CubicSpline(t, e, axis=0)
    n = int(np.arange(full.size)[keep].size)
    y = _stacked(Om, dt, cfg, keep, derivative=True)
    ab = (params.a_omega, params.b_omega)

    def gated(ab):
        frac, Om_model = pinned(e, Om[0], dt, params, ab[0], ab[1], speeds=True)
        g = 1.0 - frac
        Xa = _stacked(g * (Om - Om0), dt, cfg, keep)
        # instrument of the measured speeds: the model's own, uncorrelated with telemetry noise
        Za = _stacked(g * (Om_model - Om0), dt, cfg, keep)
        gs = _stacked(g, dt, cfg, keep)
        Xc = np.zeros((4 * n, 4))
        for i in range(4):
            Xc[i * n : (i + 1) * n, i] = gs[i * n : (i + 1) * n]
        return g, (Xa, Za), Xc

    def inputs(tau):
        es, ed = spline(t - tau), spline(t - tau, 1)
        Xb = _stacked(g * (es - e0), dt, cfg, keep)
        Xd = _stacked(g * ed, dt, cfg, keep)
        return Xb, Xd

    def fit(Xa, Xc, tau, b_est):
        """Gauss-Newton on the latency for a fixed gate: ``(theta, tau, b)``."""
        th = None
        for _ in range(12):
            Xb, Xd = inputs(tau)
            H = np.column_stack([Xa[0], Xb, Xc] + ([-b_est * Xd] if b_est is not None else []))
            if cfg.motor_instrument:
                Z = H.copy()
                Z[:, 0] = Xa[1]
                th = np.linalg.solve(Z.T @ H, Z.T @ y)
            elif rotor_var > 0:
                M = H.T @ H
                M[0, 0] -= H.shape[0] * rotor_var  # bias-compensated (errors in variables)
                th = np.linalg.solve(M, H.T @ y)
            else:
                th = np.linalg.lstsq(H, y, rcond=None)[0]
            b_est = float(th[1])
            step = float(th[6]) if th.size > 6 else 0.0
            tau = float(np.clip(tau + step, -max_delay, max_delay))
            if th.size > 6 and abs(step) < 1e-8:
                break
        return th, tau, b_est

    g, Xa, Xc = gated(ab)
    tau, b_est = 0.0, None
    for _ in range(8):  # the pinned intervals of the identified motors (a fixed point)
        th, tau, b_est = fit(Xa, Xc, tau, b_est)
        if not np.any(g == 0) or not th[0] < 0 < th[1]:
            break
        g_new, Xa_new, Xc_new = gated((-float(th[0]), b_est))
        if np.array_equal(g_new, g):
            break
        g, Xa, Xc = g_new, Xa_new, Xc_new
    assert b_est is not None  # the loop above fits at least once
    held = float(np.max(1.0 - np.mean(g[keep], axis=0)))
    if held > cfg.motor_max_pinned:
        return None, f"a rotor at its speed limit {100 * held:.1f} % of the time"
    if abs(tau) >= max_delay:
        return None, f"latency at the search bound {max_delay:g} s"
    Xb, Xd = inputs(tau)
    H = np.column_stack([Xa[0], Xb, Xc, -b_est * Xd])
    labels = ("a", "b", "bias0", "bias1", "bias2", "bias3", "delay")
    if cfg.motor_instrument:
        Z = H.copy()
        Z[:, 0] = Xa[1]
        return ee.RowDesign(8, y, H, (), (), labels, stack=4, Z=Z), tau
    noise = np.array([rotor_var] + [0.0] * 6) if rotor_var > 0 else None
    return ee.RowDesign(8, y, H, (), (), labels, stack=4, noise_var=noise), tau
