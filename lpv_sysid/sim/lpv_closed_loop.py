"""LPV closed loop of seed 0 Eq. (33) at nominal parameters theta0.

    x' = A(v_d, theta0) (x - x0(v_d)) + B_c(theta0) (u_c - u0(v_d)) + B_e(theta0) kappa u_e + x0'

with the static LPV state feedback of Eq. (31), ``u_c = u0(v_d) + K(v_d) (x - x0(v_d))``,
``B_e = B_c R`` (Eq. 19), the equilibrium rate of Eq. (34), ``x0' = dx0/dv_d * dv_d/dt``, and
the performance output of Eq. (18), ``z = Q^-1 (v - v_d)``. Eq. (19b) writes it as
``z = C dx = Q^-1 (v - v0(v_d))``, which is the same signal when the equilibrium velocity
``v0(v_d)`` of the vertex models equals ``v_d``; identified equilibria need not (seed 0 Table 1),
so both are reported: ``z`` / ``gain`` (Eq. 18) and ``z_model`` / ``gain_model`` (Eq. 19b, the
output the Lemma 1 certificate bounds).
Because ``B_e kappa u_e = B_c R kappa u_e`` the right-hand side is evaluated as
``A dx + B (u - u0) + x0'`` with the total command ``u = u_c + R kappa u_e`` (Eq. 17); a
saturating law can therefore be plugged in unchanged.

The scheduled quantities ``A(v_d), B(v_d), K(v_d), x0(v_d), u0(v_d), dx0/dv_d`` come from an
object implementing :class:`ScheduledModel` (in the product: the multilinear interpolation of
``lpv_sysid.models.lpv`` over the vertices of ``vertex_models.yaml`` and ``gains.yaml``; see
:mod:`lpv_sysid.sim.phase2`). This module never interpolates by itself.

Signals are first-order hold (piecewise linear between samples, as ``scipy.signal.lsim``):
``v_d(t)`` and ``u_e(t)`` are linearly interpolated and ``dv_d/dt`` is the slope of the
current segment, so Eq. (34) is exact for the interpolated reference.

Reference feedforward (synthesis/feedforward.py, seed 2 Sec. 5.1). Eq. (33) is kept as the
seed's: its ``x0'`` term moves the equilibrium with v_d for free, so the reference is already a
trajectory of Eq. (33) by construction and the seed's law needs no feedforward there (adding the
feedforward *and* keeping ``x0'`` would ask for the acceleration twice). The linear counterpart
of the real vehicle drops ``x0'`` (``moving_equilibrium=False``: ``x' = A (x - x0) + B (u - u0)``,
the equilibrium does not move by itself) and flies :func:`feedforward_law`,
``u = u0 + du_ff + K (x - x0 - dx_ff) + R kappa u_e``: there the feedforward has to make the
reference a trajectory, which it does by construction of F_i from the same (A_i, B_i) up to the
neglected dF/dt and snap terms; :mod:`lpv_sysid.sim.phase2` reports it as ``linear_ff``.

Evaluation: for the product's models and laws (a ``models.lpv.ScheduledLpv`` with
:func:`linear_lpv_law` or :func:`feedforward_law`) :func:`simulate_eq33` uses
:func:`fused_eq33`: the weights of Eq. (21) and their rate (Eq. 34) as plain floats and all
scheduled quantities from one ``[alpha; beta] @ W`` product -- the values of
:func:`eq33_rhs` through the ``ScheduledModel`` methods up to summation order, ~25x faster;
any other model or law goes through :func:`eq33_rhs`.

Integration: ``method="RK45"`` uses ``scipy.integrate.solve_ivp`` (Dormand-Prince, the
algorithm of Matlab's ode45 that the seed used), restarted on every sample interval so the
kinks of the interpolated signals are step boundaries (one call over the whole horizon
straddles them and loses ~4 digits); ``method="rk4"`` is a fixed-step classical Runge-Kutta on the
signal grid, with each sample interval split into enough sub-steps that
``h * max|eig(A + B K)| <= rk4_lambda_h`` (RK4's stability region reaches 2.78 on the real axis;
the default 0.5 keeps the error small). Both report the solution on the signal grid.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Protocol, Sequence, cast

import numpy as np
from scipy.integrate import solve_ivp

from lpv_sysid.errors import ConfigError, SafetyError

log = logging.getLogger(__name__)

#: indices of the body velocity ``u, v, w`` in the 12-state of DESIGN.md (seed 0 Eq. 14).
VELOCITY_INDEX = (2, 3, 4)


class ScheduledModel(Protocol):
    """Nominal polytopic LPV model plus LPV gains, evaluated at a scheduling point v_d (3,)."""

    def A(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_x, n_x), Eq. (21)
    def B(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_x, n_u), B_c of Eq. (19)
    def K(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_u, n_x), Eq. (31)
    def x0(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_x,)
    def u0(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_u,)
    def dx0_dvd(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_x, 3), Eq. (34)


# A control law u = law(t, x, v_d, ue_scaled) returning the total virtual command (Eq. 17).
ControlLaw = Callable[[float, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class ReferenceSignals:
    """Sampled reference v_d (N, 3) and normalised excitation u_e (N, n_e) on grid t (N,).

    First-order hold between samples (see module docstring).
    """

    t: np.ndarray
    v_d: np.ndarray
    u_e: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        v_d = np.atleast_2d(np.asarray(self.v_d, dtype=float))
        u_e = np.atleast_2d(np.asarray(self.u_e, dtype=float))
        if t.ndim != 1 or t.size < 2:
            raise ConfigError(
                f"signals: 't' must be a 1-D grid with >= 2 samples, got shape {t.shape}"
            )
        if not np.all(np.diff(t) > 0):
            raise ConfigError("signals: 't' must be strictly increasing")
        for name, arr in (("v_d", v_d), ("u_e", u_e)):
            if arr.shape[0] != t.size:
                raise ConfigError(
                    f"signals: '{name}' has {arr.shape[0]} samples, 't' has {t.size}"
                )
            if not np.all(np.isfinite(arr)):
                raise ConfigError(f"signals: '{name}' contains NaN or inf")
        if v_d.shape[1] != 3:
            raise ConfigError(
                f"signals: 'v_d' must have 3 columns (u_d, v_d, w_d), got {v_d.shape[1]}"
            )
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "v_d", v_d)
        object.__setattr__(self, "u_e", u_e)

    @property
    def dt(self) -> float:
        return float(np.min(np.diff(self.t)))

    def segment(self, t: float) -> int:
        """Index k of the FOH segment [t_k, t_k+1] containing t (clamped to the grid)."""
        k = int(np.searchsorted(self.t, t, side="right")) - 1
        return min(max(k, 0), self.t.size - 2)

    def at(
        self, t: float, segment: Optional[int] = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(v_d(t), dv_d/dt(t), u_e(t)) with first-order hold.

        ``segment`` forces the FOH segment (a fixed-step integrator on the grid passes it so
        that the slope dv_d/dt at a segment end is the one of the current interval).
        """
        k = self.segment(t) if segment is None else segment
        t0, t1 = self.t[k], self.t[k + 1]
        s = (t - t0) / (t1 - t0)
        s = min(max(s, 0.0), 1.0)
        vd = (1.0 - s) * self.v_d[k] + s * self.v_d[k + 1]
        vd_dot = (self.v_d[k + 1] - self.v_d[k]) / (t1 - t0)
        ue = (1.0 - s) * self.u_e[k] + s * self.u_e[k + 1]
        return vd, vd_dot, ue


def fast_weights(v_d: np.ndarray, vmin: np.ndarray, vmax: np.ndarray) -> np.ndarray:
    """alpha(v_d) of seed 0 Eq. (21), clamped to the box, in the vertex order of
    ``models.lpv.box_vertices`` -- the values of ``models.lpv.multilinear_weights`` without its
    input validation and np.kron (which dominated the RK4 loop: 3 kron calls per point)."""
    t = np.clip((np.asarray(v_d, dtype=float) - vmin) / (vmax - vmin), 0.0, 1.0)
    alpha = np.ones(1)
    for tk in t.tolist():
        alpha = np.outer(alpha, (1.0 - tk, tk)).ravel()  # first axis slowest, as kron
    return alpha


class LastPointCache:
    """Wraps a ScheduledModel and remembers its values at the last scheduling point.

    Within one RK step the stages share v_d (RK4 stages 2-3, the law and the right-hand side
    all ask for A, B, K, x0, u0 at the same point), so this halves to quarters the number of
    multilinear interpolations without changing any value.
    """

    _NAMES = ("A", "B", "K", "x0", "u0", "dx0_dvd")

    def __init__(self, model: ScheduledModel) -> None:
        self.model = model
        self._cache: dict[str, tuple[bytes, np.ndarray]] = {}

    def _get(self, name: str, v_d: np.ndarray) -> np.ndarray:
        key = np.asarray(v_d, dtype=float).tobytes()
        hit = self._cache.get(name)
        if hit is not None and hit[0] == key:
            return hit[1]
        stacks = _vertex_stacks(self.model)
        if stacks is not None and name != "dx0_dvd":
            # one weight evaluation for all interpolated quantities at this point (Eq. 21, 31)
            w = self._cache.get("_alpha")
            if w is None or w[0] != key:
                pm = cast(Any, self.model).model  # a ScheduledLpv (_vertex_stacks found it)
                if not np.all(np.isfinite(v_d)):
                    raise ConfigError(
                        f"scheduling point contains NaN/inf: {np.asarray(v_d).tolist()}"
                    )
                w = (key, fast_weights(v_d, pm.vmin, pm.vmax))
                self._cache["_alpha"] = w
            val = np.tensordot(w[1], stacks[name], axes=1)
        else:
            val = np.asarray(getattr(self.model, name)(v_d), dtype=float)
        self._cache[name] = (key, val)
        return val

    def A(self, v_d):
        return self._get("A", v_d)

    def B(self, v_d):
        return self._get("B", v_d)

    def K(self, v_d):
        return self._get("K", v_d)

    def x0(self, v_d):
        return self._get("x0", v_d)

    def u0(self, v_d):
        return self._get("u0", v_d)

    def dx0_dvd(self, v_d):
        return self._get("dx0_dvd", v_d)


def _vertex_stacks(model: Any) -> Optional[dict[str, np.ndarray]]:
    """Vertex stacks of a :class:`lpv_sysid.models.lpv.ScheduledLpv` (else None)."""
    pm, Kv = getattr(model, "model", None), getattr(model, "Kv", None)
    if pm is None or Kv is None or not hasattr(pm, "weights"):
        return None
    return {"A": pm.A, "B": pm.B, "K": Kv, "x0": pm.x0, "u0": pm.u0}


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


def linear_lpv_law(model: ScheduledModel, R: np.ndarray) -> ControlLaw:
    """Unsaturated law of Eqs. (17), (31): u = u0(v_d) + K(v_d)(x - x0(v_d)) + R (kappa u_e).

    ``ue_scaled`` passed to the returned function is already ``kappa u_e``.
    """
    R = np.asarray(R, dtype=float)

    def law(t: float, x: np.ndarray, v_d: np.ndarray, ue_scaled: np.ndarray) -> np.ndarray:
        return model.u0(v_d) + model.K(v_d) @ (x - model.x0(v_d)) + R @ ue_scaled

    setattr(law, "eq33_parts", ("linear", model, R, None, None))  # lets simulate_eq33 fuse it
    return law


class FeedforwardSchedule:
    """Vertex feedforward matrices F_i (and F_jerk,i) interpolated with the weights of Eq. (21).

    ``F`` (N, n_free + m, p) rows free states then inputs; ``F_jerk`` (N, n_free + m + n_rate, p)
    rows free states, inputs, rate states (synthesis/feedforward.py); ``free_index`` /
    ``rate_index`` positions of those states in x."""

    def __init__(
        self,
        vmin,
        vmax,
        F: np.ndarray,
        free_index: Sequence[int],
        n_x: int,
        F_jerk: Optional[np.ndarray] = None,
        rate_index: Sequence[int] = (),
    ) -> None:
        self.vmin = np.asarray(vmin, dtype=float)
        self.vmax = np.asarray(vmax, dtype=float)
        self.F = np.asarray(F, dtype=float)
        self.Fj = None if F_jerk is None else np.asarray(F_jerk, dtype=float)
        self.free = list(free_index)
        self.rate = list(rate_index)
        self.n_x = n_x
        if self.F.ndim != 3 or self.F.shape[1] <= len(self.free):
            raise ConfigError(f"feedforward: F must be (N, n_free + m, p), got {self.F.shape}")
        self._last: Optional[tuple] = None

    def _at(self, v_d: np.ndarray) -> tuple[np.ndarray, Optional[np.ndarray]]:
        """F(v_d), F_jerk(v_d); the last point is cached (RK stages and the law share v_d)."""
        key = np.asarray(v_d, dtype=float).tobytes()
        if self._last is None or self._last[0] != key:
            alpha = fast_weights(v_d, self.vmin, self.vmax)
            self._last = (
                key,
                np.tensordot(alpha, self.F, axes=1),
                None if self.Fj is None else np.tensordot(alpha, self.Fj, axes=1),
            )
        return self._last[1], self._last[2]

    def offsets(
        self, v_d: np.ndarray, a: np.ndarray, j: Optional[np.ndarray] = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(dx_ff (n_x,), du_ff (m,)) = F(v_d) a (+ F_jerk(v_d) j)."""
        Fv, Fjv = self._at(v_d)
        nf = len(self.free)
        y = Fv @ np.asarray(a, dtype=float)
        dx = np.zeros(self.n_x)
        dx[self.free] = y[:nf]
        du = y[nf:].copy()
        if Fjv is not None and j is not None:
            yj = Fjv @ np.asarray(j, dtype=float)
            m = du.size
            dx[self.free] += yj[:nf]
            du += yj[nf : nf + m]
            dx[self.rate] += yj[nf + m :]
        return dx, du


def feedforward_law(
    model: ScheduledModel, R: np.ndarray, ffs: FeedforwardSchedule, accel: Callable[[float], tuple]
) -> ControlLaw:
    """u = u0 + du_ff + K (x - x0 - dx_ff) + R (kappa u_e), (dx_ff, du_ff) from ``ffs`` at
    ``accel(t) = (a, j)`` (seed 2 Eq. 102 on seed 0 Eq. 31)."""
    R = np.asarray(R, dtype=float)
    if not isinstance(model, LastPointCache):
        model = LastPointCache(model)

    def law(t: float, x: np.ndarray, v_d: np.ndarray, ue_scaled: np.ndarray) -> np.ndarray:
        a, j = accel(t)
        dx, du = ffs.offsets(v_d, a, j)
        return model.u0(v_d) + du + model.K(v_d) @ (x - model.x0(v_d) - dx) + R @ ue_scaled

    setattr(law, "eq33_parts", ("feedforward", model, R, ffs, accel))  # for _FusedEq33
    return law


class _FusedEq33:
    """Seed 0 Eq. (33) for a :class:`lpv_sysid.models.lpv.ScheduledLpv` under the laws of
    :func:`linear_lpv_law` / :func:`feedforward_law`, evaluated with plain floats and one
    matrix product: the multilinear weights alpha(v_d) of Eq. (21) and beta = (d alpha /
    d v_d) dv_d/dt of Eq. (34) are computed as floats, then ``[alpha; beta] @ W`` gives every
    scheduled quantity at once (W: per vertex A, B, K, x0, u0 and the feedforward maps,
    row-stacked). Same values as :func:`eq33_rhs` through the ``ScheduledModel`` methods up to
    rounding (summation order), without numpy's per-call overhead on 8-element weight
    vectors (``np.kron``, ``tensordot``). ``moving_equilibrium`` as in :func:`eq33_rhs`."""

    def __init__(
        self,
        sched: Any,
        law_parts: tuple,
        signals: "ReferenceSignals",
        kappa: float,
        moving_equilibrium: bool,
        law_sched: Any = None,
    ) -> None:
        kind, _model, R, ffs, accel = law_parts
        pm = sched.model
        lm = law_sched if law_sched is not None else sched  # the law's schedule (K, x0, u0)
        A, B, Kv = np.asarray(pm.A, float), np.asarray(pm.B, float), np.asarray(lm.Kv, float)
        N, n, m = A.shape[0], A.shape[1], B.shape[2]
        self.n, self.m = n, m
        self.lo = [float(v) for v in pm.vmin]
        self.span = [float(b - a) for a, b in zip(pm.vmin, pm.vmax)]
        self.p = len(self.lo)
        if N != 2**self.p:
            raise ConfigError(f"Eq. (33): {N} vertices for a {self.p}-axis box")
        if not (np.array_equal(lm.model.vmin, pm.vmin) and np.array_equal(lm.model.vmax, pm.vmax)):
            raise ConfigError("Eq. (33): the law's schedule and the model have different boxes")
        cols = [
            A.reshape(N, -1),
            B.reshape(N, -1),
            Kv.reshape(N, -1),
            np.asarray(pm.x0, float),
            np.asarray(pm.u0, float),
            np.asarray(lm.model.x0, float),
            np.asarray(lm.model.u0, float),
        ]
        self.ff = None
        if kind == "feedforward":
            if not (np.array_equal(ffs.vmin, pm.vmin) and np.array_equal(ffs.vmax, pm.vmax)):
                raise ConfigError("feedforward schedule and model have different boxes")
            # F_i (free states, inputs) and F_jerk,i (free, inputs, rate states) scattered into
            # one (n + m) x (p + p_j) map per vertex: [dx_ff; du_ff] = M(v_d) [a; j]
            nf, pa = len(ffs.free), ffs.F.shape[2]
            pj = 0 if ffs.Fj is None else ffs.Fj.shape[2]
            Mv = np.zeros((N, n + m, pa + pj))
            Mv[:, ffs.free, :pa] = ffs.F[:, :nf]
            Mv[:, n:, :pa] = ffs.F[:, nf : nf + m]
            if pj:
                Mv[:, ffs.free, pa:] = ffs.Fj[:, :nf]
                Mv[:, n:, pa:] = ffs.Fj[:, nf : nf + m]
                Mv[:, ffs.rate, pa:] += ffs.Fj[:, nf + m :]
            cols.append(Mv.reshape(N, -1))
            self.ff = (accel, pa, pj)
            self._acc = (None, None)
        sizes = [c.shape[1] for c in cols]
        edges = np.cumsum([0] + sizes)
        self.sl = [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
        self.W = np.ascontiguousarray(np.hstack(cols))
        self.R = np.asarray(R, dtype=float)
        self.kappa = float(kappa)
        self.moving = bool(moving_equilibrium)
        self.sig = signals
        self._t = signals.t.tolist()
        self._vd = signals.v_d.tolist()
        self._ue = signals.u_e
        self._last = None

    # -- scheduling -------------------------------------------------------------
    def weights(self, vd, vd_dot=None):
        """(alpha, beta) as float lists: Eq. (21) weights (box clamped, first axis slowest as
        ``models.lpv.box_vertices``) and their rate along dv_d/dt (0 on a clamped axis)."""
        if self.p == 3:
            return self._weights3(vd, vd_dot)
        t, inside = [], []
        for v, lo, sp in zip(vd, self.lo, self.span):
            r = (v - lo) / sp
            inside.append(0.0 <= r <= 1.0)
            t.append(0.0 if r < 0.0 else (1.0 if r > 1.0 else r))
        alpha = [1.0]
        for tk in t:
            alpha = [a * w for a in alpha for w in (1.0 - tk, tk)]
        if vd_dot is None:
            return alpha, None
        beta = [0.0] * len(alpha)
        for k in range(self.p):
            if not inside[k] or vd_dot[k] == 0.0:
                continue
            g = [1.0]
            for l_, tl in enumerate(t):
                d = (-1.0 / self.span[k], 1.0 / self.span[k]) if l_ == k else (1.0 - tl, tl)
                g = [a * w for a in g for w in d]
            dk = vd_dot[k]
            beta = [b + gi * dk for b, gi in zip(beta, g)]
        return alpha, beta

    def _weights3(self, vd, vd_dot):
        """:meth:`weights` written out for the three axes (u_d, v_d, w_d) of the product."""
        (l0, l1, l2), (s0, s1, s2) = self.lo, self.span
        r0, r1, r2 = (vd[0] - l0) / s0, (vd[1] - l1) / s1, (vd[2] - l2) / s2
        x = 0.0 if r0 < 0.0 else (1.0 if r0 > 1.0 else r0)
        y = 0.0 if r1 < 0.0 else (1.0 if r1 > 1.0 else r1)
        z = 0.0 if r2 < 0.0 else (1.0 if r2 > 1.0 else r2)
        X, Y, Z = 1.0 - x, 1.0 - y, 1.0 - z
        XY, Xy, xY, xy = X * Y, X * y, x * Y, x * y
        alpha = [XY * Z, XY * z, Xy * Z, Xy * z, xY * Z, xY * z, xy * Z, xy * z]
        if vd_dot is None:
            return alpha, None
        beta = [0.0] * 8
        if 0.0 <= r0 <= 1.0 and vd_dot[0] != 0.0:
            a, b = -1.0 / s0, 1.0 / s0
            aY, ay, bY, by = a * Y, a * y, b * Y, b * y
            g = (aY * Z, aY * z, ay * Z, ay * z, bY * Z, bY * z, by * Z, by * z)
            d = vd_dot[0]
            beta = [bi + gi * d for bi, gi in zip(beta, g)]
        if 0.0 <= r1 <= 1.0 and vd_dot[1] != 0.0:
            a, b = -1.0 / s1, 1.0 / s1
            Xa, Xb, xa, xb = X * a, X * b, x * a, x * b
            g = (Xa * Z, Xa * z, Xb * Z, Xb * z, xa * Z, xa * z, xb * Z, xb * z)
            d = vd_dot[1]
            beta = [bi + gi * d for bi, gi in zip(beta, g)]
        if 0.0 <= r2 <= 1.0 and vd_dot[2] != 0.0:
            a, b = -1.0 / s2, 1.0 / s2
            g = (XY * a, XY * b, Xy * a, Xy * b, xY * a, xY * b, xy * a, xy * b)
            d = vd_dot[2]
            beta = [bi + gi * d for bi, gi in zip(beta, g)]
        return alpha, beta

    def at(self, vd, vd_dot=None):
        """Scheduled quantities at v_d: (A, B, K, x0, u0, x0_dot or None, F, F_jerk, x0 and
        u0 of the law's schedule)."""
        key = (tuple(vd), None if vd_dot is None else tuple(vd_dot))
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        if not all(map(math.isfinite, vd)):
            raise ConfigError(f"scheduling point contains NaN/inf: {list(vd)}")
        alpha, beta = self.weights(vd, vd_dot if self.moving else None)
        P = (np.array([alpha, beta]) if beta is not None else np.array([alpha])) @ self.W
        n, m, sl = self.n, self.m, self.sl
        row = P[0]
        out = (
            row[sl[0]].reshape(n, n),
            row[sl[1]].reshape(n, m),
            row[sl[2]].reshape(m, n),
            row[sl[3]],
            row[sl[4]],
            P[1, sl[3]] if beta is not None else None,
            row[sl[7]] if len(sl) > 7 else None,
            None,
            row[sl[5]],
            row[sl[6]],
        )
        self._last = (key, out)
        return out

    def _offsets(self, t, Mv, _unused=None):
        """(dx_ff, du_ff) of :meth:`FeedforwardSchedule.offsets` from the scattered map M(v_d);
        ``accel(t)`` is asked once per time (RK4 stages 2 and 3 share it)."""
        accel, pa, pj = self.ff
        if self._acc[0] != t:
            self._acc = (t, accel(t))
        a, j = self._acc[1]
        M = Mv.reshape(self.n + self.m, pa + pj)
        if pj and j is not None:
            dd = M @ np.concatenate([np.asarray(a, dtype=float), np.asarray(j, dtype=float)])
        else:
            dd = M[:, :pa] @ np.asarray(a, dtype=float)
        return dd[: self.n], dd[self.n :]

    # -- law and right-hand side ---------------------------------------------------
    def law(self, t: float, x: np.ndarray, v_d, ue_scaled) -> np.ndarray:
        """The total command u of the fused law (Eq. 17 / 31, with feedforward if any)."""
        _A, _B, K, _x0, _u0, _, Fv, Fjv, x0l, u0l = self.at([float(v) for v in v_d])
        Re = self.R @ np.asarray(ue_scaled, dtype=float)
        if self.ff is None:
            return u0l + K @ (x - x0l) + Re
        dx, du = self._offsets(t, Fv, Fjv)
        return u0l + du + K @ (x - x0l - dx) + Re

    def __call__(self, t: float, x: np.ndarray, segment: Optional[int] = None) -> np.ndarray:
        T, V = self._t, self._vd
        k = self.sig.segment(t) if segment is None else segment
        t0, t1 = T[k], T[k + 1]
        s = (t - t0) / (t1 - t0)
        s = 0.0 if s < 0.0 else (1.0 if s > 1.0 else s)
        r = 1.0 - s
        a, b = V[k], V[k + 1]
        vd = [r * a[0] + s * b[0], r * a[1] + s * b[1], r * a[2] + s * b[2]]
        vdot = [(b[0] - a[0]) / (t1 - t0), (b[1] - a[1]) / (t1 - t0), (b[2] - a[2]) / (t1 - t0)]
        A, B, K, x0, u0, x0dot, Fv, Fjv, x0l, u0l = self.at(vd, vdot)
        ue = r * self._ue[k] + s * self._ue[k + 1]
        Re = self.R @ (self.kappa * ue)
        if self.ff is None:
            u = u0l + K @ (x - x0l) + Re
        else:
            dxf, duf = self._offsets(t, Fv, Fjv)
            u = u0l + duf + K @ (x - x0l - dxf) + Re
        xdot = A @ (x - x0) + B @ (u - u0)
        if x0dot is not None:
            xdot += x0dot
        return xdot


def fused_eq33(
    model: Any,
    signals: "ReferenceSignals",
    law: Optional[ControlLaw],
    R: np.ndarray,
    kappa: float,
    moving_equilibrium: bool = True,
) -> Optional[_FusedEq33]:
    """The fused Eq. (33) right-hand side ``f(t, x, segment)`` (:class:`_FusedEq33`) for
    ``model`` (a ScheduledLpv, possibly wrapped in :class:`LastPointCache`) and ``law``
    (None: :func:`linear_lpv_law` with ``R``; else a law made by :func:`linear_lpv_law` or
    :func:`feedforward_law` for the same model); None for any other model or law, which
    :func:`simulate_eq33` then evaluates through :func:`eq33_rhs`."""
    inner = model.model if isinstance(model, LastPointCache) else model
    if _vertex_stacks(inner) is None:
        return None
    parts = ("linear", inner, R, None, None) if law is None else getattr(law, "eq33_parts", None)
    if parts is None:
        return None
    owner = parts[1].model if isinstance(parts[1], LastPointCache) else parts[1]
    if _vertex_stacks(owner) is None:
        return None
    try:
        return _FusedEq33(inner, parts, signals, kappa, moving_equilibrium, law_sched=owner)
    except ConfigError:  # e.g. the law's schedule has another box: evaluate generically
        return None


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


@dataclass(frozen=True)
class ClosedLoopConfig:
    """How Eq. (33) is integrated (see module docstring)."""

    kappa: float = 1.0
    method: str = "RK45"
    rtol: float = 1e-7
    atol: float = 1e-9
    rk4_lambda_h: float = 0.5
    # states whose magnitude above this bound marks the run as diverged (finiteness always checked)
    divergence_bound: float = 1e6

    def __post_init__(self) -> None:
        if not (np.isfinite(self.kappa) and self.kappa > 0):
            raise ConfigError(f"kappa must be a finite number > 0, got {self.kappa!r}")
        if self.method not in ("RK45", "rk4"):
            raise ConfigError(f"method must be 'RK45' or 'rk4', got {self.method!r}")


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


def _closed_loop_rate(model: ScheduledModel, signals: ReferenceSignals) -> float:
    """max |eig(A + B K)| over the signal's scheduling samples (for the RK4 sub-step)."""
    idx = np.unique(np.linspace(0, signals.t.size - 1, min(signals.t.size, 25)).astype(int))
    rate = 0.0
    for k in idx:
        vd = signals.v_d[k]
        acl = model.A(vd) + model.B(vd) @ model.K(vd)
        rate = max(rate, float(np.max(np.abs(np.linalg.eigvals(acl)))))
    return rate


def _rk4(
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
            raise _Diverged(t[k + 1], x, steps)
        x[k + 1] = xi
    return x, steps


def _rk45_segments(
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


class _Diverged(Exception):
    def __init__(self, t_fail: float, x: np.ndarray, steps: int) -> None:
        super().__init__(t_fail)
        self.t_fail, self.x, self.steps = t_fail, x, steps


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
        x, n_steps = _rk45_segments(f, t, x_start, config)
        info["nfev"] = n_steps
    else:
        rate = _closed_loop_rate(model, signals)
        n_sub = max(1, int(np.ceil(signals.dt * rate / config.rk4_lambda_h)))
        info["rk4_substeps"] = n_sub
        info["max_closed_loop_rate"] = rate
        try:
            x, n_steps = _rk4(f, t, x_start, n_sub, config.divergence_bound)
        except _Diverged as exc:
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


def hinf_norm_grid(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    D: Optional[np.ndarray] = None,
    w: Optional[np.ndarray] = None,
) -> tuple[float, float]:
    """Peak max singular value of G(jw) = C (jwI - A)^-1 B + D over a frequency grid.

    An independent check of Eq. (29) at a frozen parameter: it does not use any LMI. The
    grid maximum is refined with a bounded scalar search around the best grid point. Returns
    (norm, frequency in rad/s). Unstable A -> inf.
    """
    from scipy.optimize import minimize_scalar

    A = np.asarray(A, dtype=float)
    if np.max(np.real(np.linalg.eigvals(A))) >= 0:
        return float("inf"), float("nan")
    B = np.asarray(B, dtype=float)
    C = np.asarray(C, dtype=float)
    D = np.zeros((C.shape[0], B.shape[1])) if D is None else np.asarray(D, dtype=float)
    n = A.shape[0]
    eye = np.eye(n)

    def sigma(wk: float) -> float:
        G = C @ np.linalg.solve(1j * wk * eye - A, B) + D
        return float(np.linalg.svd(G, compute_uv=False)[0])

    if w is None:
        rates = np.abs(np.linalg.eigvals(A))
        lo, hi = max(1e-4, 0.01 * rates.min()), 100.0 * rates.max()
        w = np.concatenate([[0.0], np.logspace(np.log10(lo), np.log10(hi), 2000)])
    s = np.array([sigma(wk) for wk in w])
    k = int(np.argmax(s))
    best, wbest = float(s[k]), float(w[k])
    a = w[max(k - 1, 0)]
    b = w[min(k + 1, w.size - 1)]
    if b > a:
        res = minimize_scalar(
            lambda wk: -sigma(wk),
            bounds=(a, b),
            method="bounded",
            options={"xatol": 1e-10 * max(1.0, b)},
        )
        if -res.fun > best:
            best, wbest = float(-res.fun), float(res.x)
    return best, wbest
