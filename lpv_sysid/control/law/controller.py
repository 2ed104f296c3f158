"""Runtime robust LPV law of seed 0 Eqs. (17), (31): u = u0(v_d) + K(v_d) (x - x0(v_d)) + R u_e,
with the optional reference feedforward of seed 2 Sec. 5.1 (Eq. 102):
u = u0(v_d) + du_ff + K(v_d) (x - x0(v_d) - dx_ff) + R u_e, (dx_ff, du_ff) = F(v_d) a.

One :meth:`LpvController.step` does, in this order:

1. input check: NaN/inf in x, v_d, u_e or t -> :class:`SafetyError`; time going backwards ->
   :class:`SafetyError`;
2. multilinear weights alpha_i(v_d) (seed 0 Eq. 21, vertex order of ``models.lpv.box_vertices``);
   v_d outside the box is clamped onto it and ``info["clamped"]`` is set (the safety supervisor
   decides what to do with it);
3. one small matrix product ``alpha @ W_step`` with the precomputed per-vertex stack of
   :mod:`lpv_sysid.control.law.packing` gives K(v_d), x0(v_d), u0(v_d) (and the feedforward
   map) together;
4. the law ``u = u0 + K (x - x0) + R u_e``; when the schedule carries ``F_ff`` (gains.yaml,
   :mod:`lpv_sysid.synthesis.feedforward`) and ``feedforward`` is on, the state reference
   ``x0 + dx_ff`` and input ``u0 + du_ff`` with ``(dx_ff, du_ff) = (sum_i alpha_i F_i) a`` replace
   x0, u0. ``a = dv_d/dt`` is passed by the caller (simulation: exact derivative of the signal) or,
   when not given, comes from the derivative filter of :mod:`lpv_sysid.control.law.reference_rates`
   (time constant ``ff_filter_tau``; its trade-offs are stated there). With ``F_jerk`` in the
   schedule the jerk term ``F_jerk(v_d) j`` (rate states of x_ref, more tilt/inputs; see
   synthesis/feedforward.py) is added, j = d2v_d/dt2 given by the caller or the filter's second
   stage (``ff_jerk_tau``);
5. actuator saturation through the mixer (seed 0 Eq. 7): ``u_ESC = clip(Mix^-1 u, 0, 1)``,
   ``u = Mix u_ESC`` (the mixer is a constructor argument; without it no saturation);
6. optional rate limit ``|u_k - u_{k-1}| <= rate * dt`` per channel (after saturation, and the
   result re-saturated, so the command stays feasible);
7. bound monitor: energies of ``z = Q^-1 (v - v_d)`` (Eq. 18) and ``u_e`` (rectangle rule), gain
   estimate ``sqrt(E_z / E_e)`` compared with ``gamma * margin`` only after the total excitation
   energy reaches ``min_energy`` (before that the ratio is meaningless: z also contains the
   response to initial conditions and reference changes). ``monitor_window`` (s, optional)
   replaces the running integrals by exponentially forgetting ones, ``E <- exp(-dt/W) E + term``:
   an old transient (the reference lag before the feedforward settled, a gust) is forgotten, and
   for a linear closed loop the weighted ratio is bounded by the H-inf norm of the loop shifted
   by 1/(2W) (``A + I/(2W)``), i.e. ~gamma for W well above the slowest closed-loop time constant
   (slowest pole -0.5 1/s here: W >= 10 s). z still contains the tracking part that the
   feedforward does not remove (model error, saturation); the monitor judges that too, on purpose.
   ``info["bound_exceeded"]`` latches.

Cost (bench/bench_lpv_law.py, default path ~9 us): the 3- and 4-vectors as plain floats,
one ``alpha @ W_step`` into preallocated buffers (:meth:`LpvController._prepare_step`), every
check that does not depend on the inputs precomputed at load; test_lpv_controller replays
recorded sequences against the law written from the equations above (1e-12).

The law's options are :class:`~lpv_sysid.control.law.config.LpvControllerConfig`
(validated on construction); :class:`~lpv_sysid.control.law.reference_limiter.ReferenceLimiter` is
the input conditioning the flight runtime puts in front of the law.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from lpv_sysid.control.law.config import LpvControllerConfig
from lpv_sysid.control.law.packing import (
    feedforward_arrays,
    schedule_arrays,
    step_matrix,
    vertex_stack,
)
from lpv_sysid.control.law.reference_rates import ReferenceRateFilter
from lpv_sysid.control.law.weights import box_weights
from lpv_sysid.errors import ConfigError, SafetyError


class LpvController:
    """The runtime law; ``schedule`` is a loaded gains file,
    :class:`lpv_sysid.io.formats.GainSchedule` (the one reading of gains.yaml, also the one
    ``lpv-sysid verify`` checks), or an object with its attributes ``K, x0, u0, R, Q, gamma,
    vmin, vmax`` (+ ``F_ff, F_jerk, feedforward, state_names``), e.g. the phase-2 simulation's
    problem built from a GainSchedule."""

    def __init__(
        self,
        schedule: Any,
        config: LpvControllerConfig = LpvControllerConfig(),
        mix: Optional[np.ndarray] = None,
    ) -> None:
        K, x0, u0, R, Q, gamma, vmin, vmax = schedule_arrays(schedule)
        N, m, n = K.shape
        p = vmin.size
        if N != 2**p or x0.shape != (N, n) or u0.shape != (N, m) or R.shape[0] != m:
            raise ConfigError(
                f"gain schedule shapes inconsistent: K {K.shape}, x0 {x0.shape}, u0 {u0.shape}, "
                f"R {R.shape} for a {p}-axis box"
            )
        if np.any(vmax <= vmin):
            raise ConfigError("gain schedule: scheduling box needs max > min")
        self.n_x, self.n_u, self.n_p = n, m, p
        self.vmin = vmin.copy()
        self.inv_range = 1.0 / (vmax - vmin)
        self.vmax = vmax.copy()
        ff = feedforward_arrays(schedule, n) if config.feedforward else None
        #: the per-vertex stack [vec K_i | x0_i | u0_i | vec G_i] with named column blocks
        self.stack = vertex_stack(K, x0, u0, p, ff)
        self.W = self.stack.W
        self.has_ff = self.stack.has_ff
        self.has_jerk = self.stack.has_jerk
        self.R = np.ascontiguousarray(R)
        self.n_e = R.shape[1]
        self.Qinv = np.linalg.inv(Q)
        vi = tuple(config.velocity_index)
        # a contiguous index set becomes a slice (a view, cheaper than fancy indexing)
        self.vel = (
            slice(vi[0], vi[-1] + 1)
            if vi == tuple(range(vi[0], vi[-1] + 1))
            else np.array(vi, dtype=int)
        )
        self._vel_max = max(vi)
        self._n_vel = len(vi)
        if self.Qinv.shape[0] != self._n_vel or self._vel_max >= n:
            raise ConfigError(
                f"Q is {Q.shape[0]}x{Q.shape[0]} but velocity_index is {config.velocity_index}"
            )
        self.gamma = gamma
        self.cfg = config
        self.mix: Optional[np.ndarray] = None
        self.mix_inv: Optional[np.ndarray] = None
        if mix is not None:
            mix = np.asarray(mix, dtype=float)
            if mix.shape != (m, m):
                raise ConfigError(f"mixer must be {m}x{m}, got {mix.shape}")
            self.mix = mix
            self.mix_inv = np.linalg.inv(mix)
        if config.rate_limit is not None and len(config.rate_limit) != m:
            raise ConfigError(f"rate_limit needs {m} entries, got {len(config.rate_limit)}")
        self.rate = (
            None if config.rate_limit is None else np.asarray(config.rate_limit, dtype=float)
        )
        self._rate_list = None if self.rate is None else self.rate.tolist()
        self.threshold = gamma * config.monitor_margin
        self.tau = float(config.ff_filter_tau)
        self.tau_j = float(config.ff_jerk_tau)
        self.window = config.monitor_window
        self.rate_filter = ReferenceRateFilter(p, self.tau, self.tau_j)
        self._prepare_step()
        self.reset()

    def _prepare_step(self) -> None:
        """Everything :meth:`step` can precompute from the schedule and config (load time):
        ``W_step`` and its :class:`~lpv_sysid.control.law.packing.StepLayout`
        (:func:`~lpv_sysid.control.law.packing.step_matrix`), so a step is one
        ``alpha @ W_step`` into a preallocated row whose views are the blended matrices, and
        two small products."""
        n, p, ne = self.n_x, self.n_p, self.n_e
        self.W_step, layout = step_matrix(self.stack, self.R, self.mix_inv)
        self.step_layout = layout
        self._blend = np.empty(layout.width)  # alpha @ W_step
        # views of the blended row: [K | R | G_u | u0 [; Mix^-1 (...)]](alpha) and the
        # reference map [G_x | x0](alpha) (n, q + 1), which is x0(alpha) without feedforward
        self._gain = self._blend[layout.gain].reshape(layout.gain_rows, layout.c)
        self._xref_flat = self._blend[layout.xref]
        self._xref_map = self._xref_flat.reshape(n, layout.q + 1)
        self._u_rows, self._esc_rows = layout.u_rows, layout.esc_rows
        self._xref = np.empty(n)
        self._b = np.zeros(layout.c)  # [x - x_ref; u_e; [a; j]; 1]
        self._b[layout.b_one] = 1.0
        self._b_dx = self._b[layout.b_dx]
        self._b_ue = self._b[layout.b_ue]
        self._b_rates = self._b[layout.b_rates]
        self._b_rates_one = self._b[layout.b_rates_one]
        self._vmin_l = self.vmin.tolist()
        self._ir_l = self.inv_range.tolist()
        vel = self.vel
        self._vel_l = list(range(vel.start, vel.stop)) if isinstance(vel, slice) else vel.tolist()
        self._vel_slice = vel if isinstance(vel, slice) else None
        qi = self.Qinv
        # z = Q^-1 (v - v_d): a diagonal Q (the usual weight) needs one product per axis
        self._qinv_diag = (
            np.diag(qi).tolist() if np.count_nonzero(qi - np.diag(np.diag(qi))) == 0 else None
        )
        self._qinv_l = qi.tolist()
        self._thr2 = self.threshold * self.threshold
        self._min_energy = float(self.cfg.monitor_min_energy)
        self._shapes = ((n,), (p,), (ne,))
        self._esc_lo, self._esc_hi = float(self.cfg.u_esc_min), float(self.cfg.u_esc_max)

    def reset(self) -> None:
        self.t_prev: Optional[float] = None
        self.u_prev: Optional[np.ndarray] = None
        self.energy_z = 0.0  # monitor energies (windowed when monitor_window is set)
        self.energy_e = 0.0
        self.energy_e_total = 0.0  # running excitation energy (decides when to judge)
        self.bound_exceeded = False
        self.rate_filter.reset()

    @property
    def vd_filt(self) -> Optional[np.ndarray]:
        """Low-passed v_d of the derivative filter (None before the first step)."""
        return self.rate_filter.vd_filt

    @property
    def a_lp(self) -> Optional[np.ndarray]:
        """Low-passed a (the jerk stage's state; None before the first step)."""
        return self.rate_filter.a_lp

    @property
    def a_filt(self) -> np.ndarray:
        """Filtered reference rate a = dv_d/dt of the last step."""
        return self.rate_filter.a_filt

    @property
    def j_filt(self) -> np.ndarray:
        """Filtered reference jerk j of the last step."""
        return self.rate_filter.j_filt

    def reference_rate(self, t: float, v_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Filtered first and second derivative (a, j) of the reference
        (:mod:`lpv_sysid.control.law.reference_rates`); updates the filter. The jerk is the
        derivative filter (time constant ``ff_jerk_tau``) applied to a (two cascaded stages).

        Uses the time since the previous call of :meth:`step` (``t_prev``)."""
        filt = self.rate_filter
        a, j, state = filt.rates(float(t), self.t_prev, np.asarray(v_d, dtype=float).tolist())
        filt.commit(state)
        return np.array(a), np.array(j)

    # -- pieces (public for tests) -----------------------------------------------------
    def weights(self, v_d: np.ndarray) -> tuple[np.ndarray, bool]:
        """alpha(v_d) (clamped) and the clamp flag; box order of models.lpv.box_vertices."""
        alpha, clamped = box_weights(
            np.asarray(v_d, dtype=float).tolist(), self._vmin_l, self._ir_l
        )
        return np.array(alpha), clamped

    def gain(self) -> float:
        """Running (or windowed) estimate ||z||_2 / ||u_e||_2 (NaN before any excitation)."""
        return math.sqrt(self.energy_z / self.energy_e) if self.energy_e > 0 else float("nan")

    # -- the step ----------------------------------------------------------------------
    def step(
        self,
        t: float,
        x: np.ndarray,
        v_d: np.ndarray,
        u_e: np.ndarray,
        a: Optional[np.ndarray] = None,
        j: Optional[np.ndarray] = None,
    ) -> tuple[np.ndarray, dict]:
        """One control step; ``a`` = dv_d/dt and ``j`` = d2v_d/dt2 for the feedforward (None: the
        filtered derivatives of v_d). Returns ``(u, info)``; ``u`` is a new array every step,
        ``info["a_ff"]`` / ``info["j_ff"]`` the rates the feedforward used (tuples of floats,
        None when off).

        Cost (bench/bench_lpv_law.py): the 3- and 4-vectors are handled as plain floats, the
        blend is one ``alpha @ W_step`` into a preallocated row whose views are the blended
        matrices (:meth:`_prepare_step`), products use ``ndarray.dot`` (a third of the call
        overhead of ``@`` on these sizes), and no check allocates what the load precomputed."""
        a_l = j_l = None
        if a is not None:
            a = np.asarray(a, dtype=float)
            if a.shape != (self.n_p,) or not np.all(np.isfinite(a)):
                raise SafetyError(
                    f"lpv law: reference acceleration must be {self.n_p} finite values, got {a}"
                )
            a_l = a.tolist()
        if j is not None:
            j = np.asarray(j, dtype=float)
            if j.shape != (self.n_p,) or not np.all(np.isfinite(j)):
                raise SafetyError(
                    f"lpv law: reference jerk must be {self.n_p} finite values, got {j}"
                )
            j_l = j.tolist()
        try:
            x = np.asarray(x, dtype=float)
            v_d = np.asarray(v_d, dtype=float)
            u_e = np.asarray(u_e, dtype=float)
            t = float(t)
        except (TypeError, ValueError) as exc:
            raise SafetyError(f"lpv law: non-numeric input ({exc})") from None
        sx, sv, se = self._shapes
        if x.shape != sx or v_d.shape != sv or u_e.shape != se:
            raise SafetyError(
                f"lpv law: shapes x {x.shape}, v_d {v_d.shape}, u_e {u_e.shape}; expected "
                f"({self.n_x},), ({self.n_p},), ({self.n_e},)"
            )
        vd = v_d.tolist()
        ee = float(u_e.dot(u_e))
        # one finiteness test of t, v_d and u_e: a sum of squares is NaN/inf iff an entry is
        # (or overflows, which is also refused); x follows with b below, before any state changes
        if not math.isfinite(t + float(v_d.dot(v_d)) + ee):
            raise SafetyError(_nonfinite_message(t, x, v_d, u_e))
        dt = 0.0
        t_prev = self.t_prev
        if t_prev is not None:
            dt = t - t_prev
            if dt < 0.0:
                raise SafetyError(f"lpv law: time went backwards ({t_prev} -> {t})")
        rates = None
        has_ff = self.has_ff
        if has_ff:
            if a_l is None or (self.has_jerk and j_l is None):
                # the derivative filter only runs when the caller does not supply a (and j)
                af, jf, rates = self.rate_filter.rates(t, t_prev, vd)
                if a_l is None:
                    a_l = af
                if j_l is None:
                    j_l = jf
            if not self.has_jerk:
                j_l = None
        alpha, clamped = box_weights(vd, self._vmin_l, self._ir_l)
        np.array(alpha).dot(self.W_step, out=self._blend)  # K, R, G, x0, u0 blended (Eq. 31)
        b = self._b
        if has_ff:
            self._b_rates[:] = a_l if j_l is None else a_l + j_l
            self._xref_map.dot(self._b_rates_one, out=self._xref)  # x_ref = x0 + G_x [a; j]
            np.subtract(x, self._xref, out=self._b_dx)
        else:
            np.subtract(x, self._xref_flat, out=self._b_dx)  # x_ref = x0
        self._b_ue[:] = u_e
        # x (through x - x_ref) and the feedforward rates: finite, without overflow
        if not math.isfinite(b.dot(b)):
            raise SafetyError(_nonfinite_message(t, x, v_d, u_e))
        if rates is not None:  # commit the derivative filter
            self.rate_filter.commit(rates)
        uy = self._gain.dot(b)  # u0 + du_ff + K (x - x_ref) + R u_e [; Mix^-1 of it]
        saturated = False
        if self.mix is not None:
            u = uy[self._u_rows]
            lst = uy[self._esc_rows].tolist()  # ESC commands Mix^-1 u (seed 0 Eq. 7)
            lo, hi = self._esc_lo, self._esc_hi
            if min(lst) < lo or max(lst) > hi:
                u = self.mix.dot(np.array([lo if e < lo else hi if e > hi else e for e in lst]))
                saturated = True
        else:
            u = uy
        rate_limited = False
        if self._rate_list is not None and self.u_prev is not None:
            du = (u - self.u_prev).tolist()
            if any(abs(d) > r * dt for d, r in zip(du, self._rate_list)):
                steps = [r * dt for r in self._rate_list]
                u = self.u_prev + np.array(
                    [-s if d < -s else s if d > s else d for d, s in zip(du, steps)]
                )
                rate_limited = True
                if self.mix is not None:
                    u, sat2 = self._saturate(u)
                    saturated = saturated or sat2
        self.u_prev = u
        self.t_prev = t
        # bound monitor (Eq. 18 performance output z = Q^-1 (v - v_d), Eq. 26/29 energies)
        if dt > 0.0:
            vs = self._vel_slice
            xv = x[vs].tolist() if vs is not None else [float(x[i]) for i in self._vel_l]
            qd = self._qinv_diag
            if qd is not None and len(qd) == 3:  # unrolled: diagonal Q, 3 velocities
                q0, q1, q2 = qd
                w0, w1, w2 = xv
                v0, v1, v2 = vd
                z0, z1, z2 = q0 * (w0 - v0), q1 * (w1 - v1), q2 * (w2 - v2)
                zz = z0 * z0 + z1 * z1 + z2 * z2
            elif qd is not None:
                zz = 0.0
                for qk, xk, vk in zip(qd, xv, vd):
                    zk = qk * (xk - vk)
                    zz += zk * zk
            else:
                dv = [xi - v for xi, v in zip(xv, vd)]
                zz = 0.0
                for qrow in self._qinv_l:
                    zk = 0.0
                    for qk, dk in zip(qrow, dv):
                        zk += qk * dk
                    zz += zk * zk
            if self.window is not None:
                lam = math.exp(-dt / self.window)
                self.energy_z *= lam
                self.energy_e *= lam
            self.energy_z += zz * dt
            self.energy_e += ee * dt
            self.energy_e_total += ee * dt
        judged = self.energy_e_total >= self._min_energy and self.energy_e > 0.0
        if judged and self.energy_z > self._thr2 * self.energy_e:
            self.bound_exceeded = True
        return u, {
            "clamped": clamped,
            "saturated": saturated,
            "rate_limited": rate_limited,
            "bound_judged": judged,
            "bound_exceeded": self.bound_exceeded,
            "feedforward": has_ff,
            "a_ff": None if a_l is None else tuple(a_l),
            "j_ff": None if j_l is None else tuple(j_l),
        }

    def _saturate(self, u: np.ndarray) -> tuple[np.ndarray, bool]:
        """Seed 0 Eq. 7 limits: ``u = Mix clip(Mix^-1 u, u_esc_min, u_esc_max)``."""
        mix, mix_inv = self.mix, self.mix_inv
        if mix is None or mix_inv is None:
            return u, False
        lst = mix_inv.dot(u).tolist()
        lo, hi = self._esc_lo, self._esc_hi
        if min(lst) < lo or max(lst) > hi:
            return mix.dot(np.array([lo if e < lo else hi if e > hi else e for e in lst])), True
        return u, False


def _nonfinite_message(t, x, v_d, u_e) -> str:
    bad = [
        name
        for name, a in (("t", np.atleast_1d(t)), ("x", x), ("v_d", v_d), ("u_e", u_e))
        if not np.all(np.isfinite(np.asarray(a, dtype=float)))
    ]
    return f"lpv law: non-finite input in {', '.join(bad) or 'inputs (overflow)'}"
