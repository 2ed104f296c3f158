"""Seed 0 Eq. (33) fused for the product's models and laws: plain-float weights and one
matrix product per evaluation.

For the product's models and laws (a ``models.lpv.ScheduledLpv`` with
:func:`~lpv_sysid.sim.closed_loop.laws.linear_lpv_law` or
:func:`~lpv_sysid.sim.closed_loop.laws.feedforward_law`)
:func:`~lpv_sysid.sim.closed_loop.simulate_eq33` uses :func:`fused_eq33`: the weights of
Eq. (21) and their rate (Eq. 34) as plain floats and all scheduled quantities from one
``[alpha; beta] @ W`` product -- the values of :func:`~lpv_sysid.sim.closed_loop.eq33_rhs`
through the ``ScheduledModel`` methods up to summation order, ~25x faster; any other model or
law goes through ``eq33_rhs``.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.sim.closed_loop.laws import ControlLaw
from lpv_sysid.sim.closed_loop.references import ReferenceSignals
from lpv_sysid.sim.closed_loop.schedule import LastPointCache, vertex_stacks


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
        self.ff: Optional[tuple[Any, int, int]] = None  # (accel(t), p, p_jerk)
        self._acc: tuple[Any, Any] = (None, None)  # (t, accel(t)) of the last call
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
        self._last: Optional[tuple[Any, Any]] = None  # (key, result) of the last point

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
        assert self.ff is not None  # only the feedforward kind asks for offsets
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
    if vertex_stacks(inner) is None:
        return None
    parts = ("linear", inner, R, None, None) if law is None else getattr(law, "eq33_parts", None)
    if parts is None:
        return None
    owner = parts[1].model if isinstance(parts[1], LastPointCache) else parts[1]
    if vertex_stacks(owner) is None:
        return None
    try:
        return _FusedEq33(inner, parts, signals, kappa, moving_equilibrium, law_sched=owner)
    except ConfigError:  # e.g. the law's schedule has another box: evaluate generically
        return None
