"""Loop delay in the certificate: a small-gain proof that the frozen closed loops keep
``||u_e -> z||_inf <= gamma`` when the state feedback acts with a constant delay up to a bound.

The law of seed 0 Eq. (31) acting on a state ``tau`` old, ``u_c = K x(t - tau)``, is the loop
``u_c = K x + w`` with ``w = -K (x(t) - x(t - tau)) = -int_{t-tau}^t v ds``, ``v = K xdot``. The
window integral has L2 gain ``||(1 - e^{-s tau}) / s||_inf = tau`` on every channel, so with
``Delta = D_tau / tau`` (norm <= 1, LTI for a constant delay <= tau) the delayed loop is the
frozen closed loop ``A_cl = A + B K`` with the extra channel

    xdot = A_cl x + B R u_e + B w,   z = C x,   v = K xdot = K A_cl x + K B R u_e + K B w.

Robust performance by the D-scaled small-gain test (the performance channel as a fictitious
full block; Zhou, Doyle & Glover, *Robust and Optimal Control* 1996, Thm. 11.7 and Sec. 11.3.3;
the delay form: Gu, Kharitonov & Chen, *Stability of Time-Delay Systems* 2003, Sec. 3.7): if for
some ``d > 0``

    || [C / gamma; d tau K A_cl] (sI - A_cl)^-1 [B R, B / d]
       + [0, 0; d tau K B R, tau K B] ||_inf < 1

then every delay in ``[0, tau]`` keeps the loop stable and ``||u_e -> z||_inf < gamma``. The
stability-only margin is ``1 / ||K A_cl (sI - A_cl)^-1 B + K B||_inf``. Both are frozen-plant
statements, checked here on every system the certificate stores (per vertex: the box centre,
the nominal and the seeded corners of the sidecar): it is not a common-Lyapunov proof over the
whole box, and the certificate says so (``certificate.loop_delay``).
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from lpv_sysid.synthesis.hinf import hinf_norm

#: D-scalings tried per system (log-spaced; the test holds if one of them passes)
D_GRID = tuple(float(x) for x in np.geomspace(1e-3, 1e3, 13))


def scaled_gain(
    A: np.ndarray,
    B: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    tau: float,
    d_hint: Optional[float] = None,
) -> tuple[float, float]:
    """min over ``d`` in :data:`D_GRID` (tried nearest ``d_hint`` first; stops at the first
    that passes) of the scaled norm of the module docstring (< 1: the delay ``tau`` is covered
    at ``gamma``) and that ``d``; inf when ``A + B K`` is not Hurwitz."""
    Acl = A + B @ K
    if np.max(np.linalg.eigvals(Acl).real) >= 0:
        return float("inf"), float("nan")
    best, best_d = float("inf"), float("nan")
    BR = B @ R
    nz, ne, m = C.shape[0], R.shape[1], B.shape[1]
    grid = list(D_GRID)
    if d_hint is not None and np.isfinite(d_hint) and d_hint > 0:
        grid = [float(d_hint)] + sorted(grid, key=lambda x: abs(np.log(x / d_hint)))
    for d in grid:
        Cc = np.vstack([C / gamma, d * tau * K @ Acl])
        Bc = np.hstack([BR, B / d])
        D = np.zeros((nz + m, ne + m))
        D[nz:, :ne] = d * tau * K @ BR
        D[nz:, ne:] = tau * K @ B
        val = hinf_norm(Acl, Bc, Cc, D=D).value
        if val < best:
            best, best_d = float(val), float(d)
        if best < 1.0:
            break
    return best, best_d


def stability_margin(systems: Sequence[Sequence[tuple]], K: np.ndarray) -> float:
    """Smallest ``1 / ||K A_cl (sI - A_cl)^-1 B + K B||_inf`` over the systems (s): every
    constant delay below it keeps every frozen loop stable (0 when a loop is unstable)."""
    worst = 0.0
    for i, lst in enumerate(systems):
        for A, B in lst:
            Acl = A + B @ K[i]
            worst = max(worst, hinf_norm(Acl, B, K[i] @ Acl, D=K[i] @ B).value)
    return 0.0 if not np.isfinite(worst) else (float("inf") if worst == 0 else 1.0 / worst)


def covers(
    systems: Sequence[Sequence[tuple]],
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    tau: float,
    subset: Optional[Sequence[int]] = None,
) -> tuple[bool, float, str]:
    """True when every system (``subset``: only these indices per vertex) passes the scaled test
    at ``tau``; the worst scaled value and where."""
    worst, where, hint = 0.0, "all systems", None
    for i, lst in enumerate(systems):
        idx = range(len(lst)) if subset is None else [j for j in subset if j < len(lst)]
        for j in idx:
            A, B = lst[j]
            val, d = scaled_gain(A, B, K[i], R, C, gamma, tau, hint)
            hint = d if val < 1.0 else hint
            if val > worst:
                worst, where = val, f"vertex {i} system {j}"
            if val >= 1.0:
                return False, val, where
    return True, worst, where


def performance_margin(
    systems: Sequence[Sequence[tuple]],
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    steps: int = 9,
) -> float:
    """The largest delay (within ``2^-steps`` of the stability margin) for which the scaled test
    passes on every system: bisection on the first two systems per vertex, the result then
    confirmed on all systems (shrunk by 10 % until it is)."""
    hi = stability_margin(systems, K)
    if not np.isfinite(hi) or hi <= 0:
        return 0.0
    lo = 0.0
    if not covers(systems, K, R, C, gamma, 0.0, subset=(0, 1))[0]:
        return 0.0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        if covers(systems, K, R, C, gamma, mid, subset=(0, 1))[0]:
            lo = mid
        else:
            hi = mid
    while lo > 0 and not covers(systems, K, R, C, gamma, lo)[0]:
        lo *= 0.9
    return float(lo)


def configured_delay_s(rate_hz: float, state_rate_hz: float, input_latency_s: float) -> float:
    """Worst age of the state a command acts on plus its hold, for a controller stepping at
    ``rate_hz`` on state samples published at ``state_rate_hz`` and delivered ``input_latency_s``
    late (p99): ``input_latency_s + 1 / state_rate_hz + 1 / rate_hz`` [s]."""
    return float(input_latency_s + 1.0 / state_rate_hz + 1.0 / rate_hz)
