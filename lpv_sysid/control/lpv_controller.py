"""Runtime robust LPV law of seed 0 Eqs. (17), (31): u = u0(v_d) + K(v_d) (x - x0(v_d)) + R u_e,
with the optional reference feedforward of seed 2 Sec. 5.1 (Eq. 102):
u = u0(v_d) + du_ff + K(v_d) (x - x0(v_d) - dx_ff) + R u_e, (dx_ff, du_ff) = F(v_d) a.

One :meth:`LpvController.step` does, in this order:

1. input check: NaN/inf in x, v_d, u_e or t -> :class:`SafetyError`; time going backwards ->
   :class:`SafetyError`;
2. multilinear weights alpha_i(v_d) (seed 0 Eq. 21, vertex order of ``models.lpv.box_vertices``);
   v_d outside the box is clamped onto it and ``info["clamped"]`` is set (the safety supervisor
   decides what to do with it);
3. one small matrix product ``alpha @ W`` with the precomputed stack W = [vec K_i | x0_i | u0_i]
   gives K(v_d), x0(v_d), u0(v_d) together;
4. the law ``u = u0 + K (x - x0) + R u_e``; when the schedule carries ``F_ff`` (gains.yaml,
   :mod:`lpv_sysid.synthesis.feedforward`) and ``feedforward`` is on, the state reference
   ``x0 + dx_ff`` and input ``u0 + du_ff`` with ``(dx_ff, du_ff) = (sum_i alpha_i F_i) a`` replace
   x0, u0. ``a = dv_d/dt`` is passed by the caller (simulation: exact derivative of the signal) or,
   when not given, is the derivative of the reference low-passed with time constant
   ``ff_filter_tau`` (``a = d/dt [v_d / (tau s + 1)]``, discretised exactly for a held input:
   ``y_k = y_k-1 + (1 - exp(-dt/tau)) (v_d,k - y_k-1)``, ``a_k = (y_k - y_k-1) / dt``, which gives
   the exact slope of a ramp after the transient). Trade-off: the filter delays a by ~tau (phase
   lag 2 pi f tau at frequency f: 0.2 s costs 36 deg at 0.5 Hz), a small tau passes the staircase
   of a reference stream that is slower than the control rate and its noise (gain 1/tau at high
   frequency). 0.2 s suits a 50 Hz reference with content up to ~0.5 Hz. With ``F_jerk`` in the
   schedule the jerk term ``F_jerk(v_d) j`` (rate states of x_ref, more tilt/inputs; see
   synthesis/feedforward.py) is added, j = d2v_d/dt2 given by the caller or a second stage with
   its own time constant ``ff_jerk_tau`` applied to the filtered a. Measured on the phase-2
   reference (band 0.01-0.2 Hz) held at 50 Hz and sampled at 250 Hz: a has 28 / 13 / 12 % rms
   error for tau = 0.02 / 0.05 / 0.1 s; a jerk stage of 0.05 s is useless (error 2x the signal:
   it differentiates the staircase), 0.1 s gives 60 %, hence the separate, longer ff_jerk_tau;
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

:class:`LpvControllerConfig` validates itself on construction (every path: node, replay,
simulation, library). :class:`ReferenceLimiter` is the input conditioning the flight runtime
puts in front of the law: v_d limited to the rate and acceleration envelope the gains were
designed for, so a reference step cannot become a feedforward spike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.config_fields import is_finite_number


@dataclass(frozen=True)
class LpvControllerConfig:
    """Options of the runtime law (``lpv_controller`` section of the node config), checked by
    :meth:`validate` on every construction."""

    u_esc_min: float = 0.0
    u_esc_max: float = 1.0
    rate_limit: Optional[tuple] = None  # per virtual channel, units of u per second
    monitor_margin: float = 1.2  # flag when gain > gamma * margin (>= 1)
    monitor_min_energy: float = 0.05  # ||u_e||_2^2 needed before the gain is judged
    velocity_index: tuple = (2, 3, 4)  # u, v, w in the 12-state of DESIGN.md
    feedforward: bool = True  # use the schedule's F_ff when it has one
    ff_filter_tau: float = 0.05  # s, derivative filter of v_d when a is not given
    ff_jerk_tau: float = 0.2  # s, second stage (jerk) filter when j is not given
    monitor_window: Optional[float] = (
        None  # s, exponential forgetting of the monitor (None: running)
    )

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Every rule, for every construction (node, replay, simulation, library): a config
        that exists is one the law can fly."""

        def bad(msg: str):
            raise ConfigError(f"lpv_controller: {msg}")

        def num(name: str, lo: float, hi: float = math.inf, lo_open: bool = False) -> float:
            v = getattr(self, name)
            if not is_finite_number(v) or (v <= lo if lo_open else v < lo) or v > hi:
                rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
                bad(f"{name} must be a finite number in {rng}, got {v!r}")
            return float(v)

        lo, hi = num("u_esc_min", 0.0, 1.0), num("u_esc_max", 0.0, 1.0)
        if not lo < hi:
            bad(f"need u_esc_min < u_esc_max, got {lo:g} >= {hi:g}")
        num("monitor_margin", 1.0)
        num("monitor_min_energy", 0.0, lo_open=True)
        num("ff_filter_tau", 0.0)
        num("ff_jerk_tau", 0.0)
        if self.monitor_window is not None:
            num("monitor_window", 0.0, lo_open=True)
        if self.rate_limit is not None:
            if not all(is_finite_number(r) and r > 0 for r in self.rate_limit):
                bad(
                    f"rate_limit entries must be finite and > 0 (units of u per second), "
                    f"got {list(self.rate_limit)}"
                )
        if not isinstance(self.feedforward, bool):
            bad(f"feedforward must be true or false, got {self.feedforward!r}")
        if not all(
            isinstance(i, (int, np.integer)) and not isinstance(i, bool) and i >= 0
            for i in self.velocity_index
        ):
            bad(f"velocity_index must be state indices, got {self.velocity_index!r}")

    @classmethod
    def from_dict(cls, d: Optional[dict]) -> "LpvControllerConfig":
        d = dict(d or {})
        bad = set(d) - set(cls.__dataclass_fields__)
        if bad:
            raise ConfigError(f"lpv_controller: unknown key(s) {sorted(bad)}")
        if "rate_limit" in d and d["rate_limit"] is not None:
            d["rate_limit"] = tuple(d["rate_limit"])
        if "velocity_index" in d:
            d["velocity_index"] = tuple(d["velocity_index"])
        return cls(**d)


def _schedule_arrays(schedule: Any) -> tuple:
    """(K, x0, u0, R, Q, gamma, vmin, vmax): the attributes of io.formats.GainSchedule."""
    K = np.asarray(schedule.K, dtype=float)
    x0 = np.asarray(schedule.x0, dtype=float)
    u0 = np.asarray(schedule.u0, dtype=float)
    vmin, vmax = schedule.vmin, schedule.vmax
    return (
        K,
        x0,
        u0,
        np.asarray(schedule.R, float),
        np.asarray(schedule.Q, float),
        float(schedule.gamma),
        np.asarray(vmin, float),
        np.asarray(vmax, float),
    )


def _feedforward_arrays(schedule: Any, n_x: int) -> Optional[tuple]:
    """(F (N, r, p), free state indices, F_jerk (N, r + n_rate, p) or None, rate state indices)
    of a schedule with feedforward, else None.

    ``schedule.feedforward`` is the io.formats.FeedforwardSpec of the gains file (any other
    layout object is refused); state names from ``schedule.state_names`` (quadrotor layout when
    the schedule has none)."""
    from lpv_sysid.io.formats import FeedforwardSpec

    F = getattr(schedule, "F_ff", None)
    spec = getattr(schedule, "feedforward", None)
    if F is None or spec is None:
        return None
    if not isinstance(spec, FeedforwardSpec):
        raise ConfigError(
            "gain schedule: feedforward must be the io.formats FeedforwardSpec of a gains file "
            f"read by io.formats.GainSchedule, got {type(spec).__name__}"
        )
    from lpv_sysid.models.quadrotor import STATE_NAMES

    free = list(spec.free_states)
    names = list(getattr(schedule, "state_names", None) or STATE_NAMES)
    rate = list(spec.rate_states)
    Fj = getattr(schedule, "F_jerk", None)
    if len(names) != n_x or any(s not in names for s in list(free) + list(rate)):
        raise ConfigError(
            f"feedforward states {list(free) + list(rate)} not among the schedule's states {names}"
        )
    if Fj is None or not rate:
        Fj, rate = None, []
    return (
        np.asarray(F, dtype=float),
        [names.index(s) for s in free],
        None if Fj is None else np.asarray(Fj, dtype=float),
        [names.index(s) for s in rate],
    )


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
        K, x0, u0, R, Q, gamma, vmin, vmax = _schedule_arrays(schedule)
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
        # W = [vec K_i | x0_i | u0_i]: one product alpha @ W interpolates everything (Eq. 31)
        stack = [K.reshape(N, m * n), x0, u0]
        ff = _feedforward_arrays(schedule, n) if config.feedforward else None
        self.has_ff = ff is not None
        self.has_jerk = False
        if ff is not None:
            F, free, Fj, rate = ff
            if F.shape != (N, len(free) + m, p):
                raise ConfigError(
                    f"gain schedule: F_ff has shape {F.shape}, "
                    f"expected ({N}, {len(free) + m}, {p})"
                )
            if not np.all(np.isfinite(F)):
                raise ConfigError("gain schedule: F_ff contains NaN/inf")
            self._ff_shape = F.shape[1:]
            self._ff_free = np.array(free, dtype=int)
            self._ff_nf = len(free)
            # dense per-vertex maps [a; j] -> (dx_ff over all n states, du_ff): scattered once
            # here so the step needs one small product each (G_x (n x 2p), G_u (m x 2p))
            nf = len(free)
            Gx = np.zeros((N, n, 2 * p))
            Gu = np.zeros((N, m, 2 * p))
            Gx[:, self._ff_free, :p] = F[:, :nf, :]
            Gu[:, :, :p] = F[:, nf:, :]
            if Fj is not None:
                if Fj.shape != (N, len(free) + m + len(rate), p) or not np.all(np.isfinite(Fj)):
                    raise ConfigError(
                        f"gain schedule: F_jerk has shape {Fj.shape} (expected "
                        f"({N}, {len(free) + m + len(rate)}, {p})) or is not finite"
                    )
                self.has_jerk = True
                self._fj_shape = Fj.shape[1:]
                self._fj_x = np.array(list(free) + list(rate), dtype=int)  # state rows of F_jerk
                Gx[:, self._fj_x, p:] = np.concatenate([Fj[:, :nf, :], Fj[:, nf + m :, :]], axis=1)
                Gu[:, :, p:] = Fj[:, nf : nf + m, :]
            # G(v_d) = sum alpha_i G_i, G_i = [G_x; G_u], rides on the same product as K, x0, u0
            stack.append(np.concatenate([Gx, Gu], axis=1).reshape(N, -1))
            self._aj = np.zeros(2 * p)
        self.W = np.ascontiguousarray(np.hstack(stack))
        self._mn = m * n
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
        self._prepare_step()
        self.reset()

    def _prepare_step(self) -> None:
        """Everything :meth:`step` can precompute from the schedule and config (load time).

        The law of the module docstring, items 3-5, is affine in alpha, so it is one stack
        W_step with, per vertex i,

        - ``[K_i | R | G_u,i | u0_i]`` (m x c, c = n + n_e + q + 1): u = that(alpha) @ b with
          b = [x - x_ref; u_e; [a; j]; 1]; with a mixer the rows ``Mix^-1 [K_i | ...]`` follow,
          so the same product gives the ESC commands the saturation test needs;
        - ``[G_x,i | x0_i]`` (n x (q + 1)): x_ref = that(alpha) @ [[a; j]; 1] (feedforward only;
          without it x_ref = x0(alpha)),

        so a step is one ``alpha @ W_step`` into a preallocated row whose views are the blended
        matrices, and two small products (R rides on the blend: sum alpha_i = 1, the result
        equals R u_e to rounding). ``q`` = p (F_ff), 2p (F_ff and F_jerk), 0 (no feedforward)."""
        N, n, m, p, ne = self.W.shape[0], self.n_x, self.n_u, self.n_p, self.n_e
        mn = self._mn
        K = self.W[:, :mn].reshape(N, m, n)
        x0 = self.W[:, mn : mn + n]
        u0 = self.W[:, mn + n : mn + n + m]
        q = 0
        if self.has_ff:
            q = 2 * p if self.has_jerk else p
            G = self.W[:, mn + n + m :].reshape(N, n + m, 2 * p)[:, :, :q]
            Gx, Gu = G[:, :n, :], G[:, n:, :]
        else:
            Gx, Gu = np.zeros((N, n, 0)), np.zeros((N, m, 0))
        c = n + ne + q + 1
        Kext = np.concatenate([K, np.broadcast_to(self.R, (N, m, ne)), Gu, u0[:, :, None]], axis=2)
        if self.mix_inv is not None:
            Kext = np.concatenate([Kext, np.einsum("ij,njk->nik", self.mix_inv, Kext)], axis=1)
        rows_k = Kext.shape[1]
        parts = [Kext.reshape(N, rows_k * c)]
        if self.has_ff:
            parts.append(np.concatenate([Gx, x0[:, :, None]], axis=2).reshape(N, n * (q + 1)))
        else:
            parts.append(x0)
        self.W_step = np.ascontiguousarray(np.hstack(parts))
        self._q = q
        self._row = np.empty(self.W_step.shape[1])
        self._Kext = self._row[: rows_k * c].reshape(rows_k, c)  # views of the blended row
        self._xref_src = self._row[rows_k * c :]  # x0(alpha), or [G_x | x0](alpha)
        self._Gx = self._xref_src.reshape(n, q + 1)  # (n, 1) = x0(alpha) without feedforward
        self._xref = np.empty(n)
        self._b = np.zeros(c)
        self._b[-1] = 1.0
        self._bx = self._b[:n]
        self._be = self._b[n : n + ne]
        self._ba = self._b[n + ne : n + ne + q]
        self._bs = self._b[n + ne :]  # [a; j; 1]
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
        # derivative filter state on plain floats (3-vectors: numpy's per-call overhead costs
        # more than the arithmetic); the arrays vd_filt, a_lp, a_filt, j_filt are views of it
        self._vf: Optional[list] = None  # low-passed v_d
        self._alp: Optional[list] = None  # low-passed a (second stage, jerk)
        self._af: list = [0.0] * self.n_p
        self._jf: list = [0.0] * self.n_p
        self._k_dt = math.nan  # step of the cached filter gains k1, k2
        self._k1 = self._k2 = 0.0

    @property
    def vd_filt(self) -> Optional[np.ndarray]:
        """Low-passed v_d of the derivative filter (None before the first step)."""
        return None if self._vf is None else np.array(self._vf)

    @property
    def a_lp(self) -> Optional[np.ndarray]:
        """Low-passed a (the jerk stage's state; None before the first step)."""
        return None if self._alp is None else np.array(self._alp)

    @property
    def a_filt(self) -> np.ndarray:
        """Filtered reference rate a = dv_d/dt of the last step."""
        return np.array(self._af)

    @property
    def j_filt(self) -> np.ndarray:
        """Filtered reference jerk j of the last step."""
        return np.array(self._jf)

    def _rates(self, t: float, vd: list) -> tuple:
        """The derivative filter's step (module docstring, item 4) on plain floats, without
        committing it: ``(a, j, state)``, state for :meth:`_commit_rates` (None: unchanged)."""
        vf, alp, t_prev = self._vf, self._alp, self.t_prev
        if vf is None or alp is None or t_prev is None:
            zero = [0.0] * self.n_p
            return zero, zero, (list(vd), zero, zero, zero)
        dt = t - t_prev
        if dt <= 0.0:
            return self._af, self._jf, None
        if dt != self._k_dt:  # the gains of a constant period are computed once
            self._k_dt = dt
            self._k1 = 1.0 if self.tau == 0.0 else -math.expm1(-dt / self.tau)
            self._k2 = 1.0 if self.tau_j == 0.0 else -math.expm1(-dt / self.tau_j)
        k, k2 = self._k1, self._k2
        if self.n_p == 3:  # unrolled: the quadrotor's (u, v, w)
            v0, v1, v2 = vd
            f0, f1, f2 = vf
            l0, l1, l2 = alp
            y0, y1, y2 = f0 + k * (v0 - f0), f1 + k * (v1 - f1), f2 + k * (v2 - f2)
            a0, a1, a2 = (y0 - f0) / dt, (y1 - f1) / dt, (y2 - f2) / dt
            m0, m1, m2 = l0 + k2 * (a0 - l0), l1 + k2 * (a1 - l1), l2 + k2 * (a2 - l2)
            a3 = [a0, a1, a2]
            j3 = [(m0 - l0) / dt, (m1 - l1) / dt, (m2 - l2) / dt]
            return a3, j3, ([y0, y1, y2], [m0, m1, m2], a3, j3)
        a_new, j_new, vf_new, alp_new = [], [], [], []
        for vdk, vfk, alk in zip(vd, vf, alp):
            y = vfk + k * (vdk - vfk)
            ak = (y - vfk) / dt
            y2 = alk + k2 * (ak - alk)
            a_new.append(ak)
            j_new.append((y2 - alk) / dt)
            vf_new.append(y)
            alp_new.append(y2)
        return a_new, j_new, (vf_new, alp_new, a_new, j_new)

    def _commit_rates(self, state: Optional[tuple]) -> None:
        if state is not None:
            self._vf, self._alp, self._af, self._jf = state

    def reference_rate(self, t: float, v_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Filtered first and second derivative (a, j) of the reference (module docstring, item 4);
        updates the filter. The jerk is the derivative filter (time constant ``ff_jerk_tau``)
        applied to a (two cascaded stages).

        Uses the time since the previous call of :meth:`step` (``t_prev``)."""
        a, j, state = self._rates(float(t), np.asarray(v_d, dtype=float).tolist())
        self._commit_rates(state)
        return np.array(a), np.array(j)

    # -- pieces (public for tests) -----------------------------------------------------
    def _weights_list(self, vd: list) -> tuple[list, bool]:
        """alpha(v_d) as floats (clamped onto the box) and the clamp flag."""
        if self.n_p == 3:
            # unrolled kron((1-a, a), (1-b, b), (1-c, c)): plain floats are faster than 3 np.kron
            v0, v1, v2 = vd
            l0, l1, l2 = self._vmin_l
            i0, i1, i2 = self._ir_l
            a, b, c = (v0 - l0) * i0, (v1 - l1) * i1, (v2 - l2) * i2
            clamped = not (0.0 <= a <= 1.0 and 0.0 <= b <= 1.0 and 0.0 <= c <= 1.0)
            if clamped:
                a = 0.0 if a < 0.0 else 1.0 if a > 1.0 else a
                b = 0.0 if b < 0.0 else 1.0 if b > 1.0 else b
                c = 0.0 if c < 0.0 else 1.0 if c > 1.0 else c
            a0, b0, c0 = 1.0 - a, 1.0 - b, 1.0 - c
            p00, p01, p10, p11 = a0 * b0, a0 * b, a * b0, a * b
            return [
                p00 * c0,
                p00 * c,
                p01 * c0,
                p01 * c,
                p10 * c0,
                p10 * c,
                p11 * c0,
                p11 * c,
            ], clamped
        t = [(v - lo) * ir for v, lo, ir in zip(vd, self._vmin_l, self._ir_l)]
        clamped = False
        for k, tk in enumerate(t):
            if tk < 0.0 or tk > 1.0:
                clamped = True
                t[k] = 0.0 if tk < 0.0 else 1.0
        alpha = [1.0]
        for tk in t:
            alpha = [w * f for w in alpha for f in (1.0 - tk, tk)]
        return alpha, clamped

    def weights(self, v_d: np.ndarray) -> tuple[np.ndarray, bool]:
        """alpha(v_d) (clamped) and the clamp flag; box order of models.lpv.box_vertices."""
        alpha, clamped = self._weights_list(np.asarray(v_d, dtype=float).tolist())
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
                af, jf, rates = self._rates(t, vd)
                if a_l is None:
                    a_l = af
                if j_l is None:
                    j_l = jf
            if not self.has_jerk:
                j_l = None
        alpha, clamped = self._weights_list(vd)
        np.array(alpha).dot(self.W_step, out=self._row)  # K, R, G, x0, u0 blended (Eq. 31)
        b = self._b
        if has_ff:
            self._ba[:] = a_l if j_l is None else a_l + j_l
            self._Gx.dot(self._bs, out=self._xref)  # x_ref = x0 + G_x [a; j]
            np.subtract(x, self._xref, out=self._bx)
        else:
            np.subtract(x, self._xref_src, out=self._bx)
        self._be[:] = u_e
        # x (through x - x_ref) and the feedforward rates: finite, without overflow
        if not math.isfinite(b.dot(b)):
            raise SafetyError(_nonfinite_message(t, x, v_d, u_e))
        if rates is not None:  # commit the derivative filter
            self._vf, self._alp, self._af, self._jf = rates
        uy = self._Kext.dot(b)  # u0 + du_ff + K (x - x_ref) + R u_e [; Mix^-1 of it]
        m = self.n_u
        saturated = False
        if self.mix is not None:
            u = uy[:m]
            lst = uy[m:].tolist()  # ESC commands Mix^-1 u (seed 0 Eq. 7)
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


class ReferenceLimiter:
    """The reference the law follows: v_d limited in rate and acceleration to the design
    envelope of the gains (``certificate.design``, :class:`lpv_sysid.io.formats.DesignEnvelope`),
    updated once per reference message at its header stamp.

    Per axis, with rate bound ``R1`` [m/s^2], acceleration bound ``R2`` [m/s^3] and the
    table's knot interval ``T`` (the excitation node plays the table linearly interpolated,
    so the played v_d has slope jumps at the knots): the output y has ``|dy/dt| <= R1`` and its
    slope stays within ``R2 (T + dt)`` of a smooth rate ``w_c`` that itself changes by at most
    ``R2 dt`` per message -- over any window W the slope changes by at most
    ``R2 (W + 2 T + 2 dt)``.
    A reference inside the envelope passes unchanged (bit for bit): the chord slopes of the
    linear interpolant of a signal with ``|s''| <= R2`` stay within ``R2 (T + dt)`` of s', and
    ``|s'| <= R1``. Outside it, y approaches the reference at the bounds with time-optimal
    braking (no overshoot beyond one step), so a step 0 -> 4.9 m/s becomes a ramp whose
    feedforward acceleration never exceeds R1.

    :meth:`update` also reports when the *incoming* reference exceeds the envelope by
    ``margin``: chord slope ``|dv/dt| > margin R1``, or a slope change between consecutive
    messages beyond ``margin 2 R2 (dt + T)`` (the largest change a signal inside the envelope
    can show, mean-value theorem over the knots); the caller aborts on it.
    """

    def __init__(self, rate_max, accel_max, knot_interval: float, margin: float) -> None:
        self.R1 = np.asarray(rate_max, dtype=float)
        self.R2 = np.asarray(accel_max, dtype=float)
        if (
            self.R1.shape != self.R2.shape
            or self.R1.ndim != 1
            or not (
                np.all(self.R1 > 0)
                and np.all(self.R2 > 0)
                and np.all(np.isfinite(self.R1))
                and np.all(np.isfinite(self.R2))
            )
        ):
            raise ConfigError(
                f"reference limiter: rate {self.R1.tolist()} and acceleration "
                f"{self.R2.tolist()} bounds must be positive, finite, one per axis"
            )
        if not (is_finite_number(knot_interval) and knot_interval >= 0.0):
            raise ConfigError(
                f"reference limiter: knot interval must be >= 0, got {knot_interval!r}"
            )
        if not (is_finite_number(margin) and margin >= 1.0):
            raise ConfigError(f"reference limiter: margin must be >= 1, got {margin!r}")
        self.T = float(knot_interval)
        self.margin = float(margin)
        self.reset()

    def reset(self) -> None:
        self.y: Optional[np.ndarray] = None  # the limited reference
        self.w = np.zeros(self.R1.size)  # its slope
        self.wc = np.zeros(self.R1.size)  # the smooth rate it stays close to
        self.t: Optional[float] = None
        self.r_prev: Optional[np.ndarray] = None
        self.w_in: Optional[np.ndarray] = None  # chord slope of the incoming reference
        self.limited = 0  # messages on which the limiter acted

    def update(self, t: float, r) -> tuple[np.ndarray, Optional[str]]:
        """The limited reference after the message ``(t, r)``, and a description of how the
        incoming reference exceeds the envelope by the margin (None when it does not). A
        stamp not after the previous one changes nothing (the supervisor judges stamps)."""
        r = np.array(r, dtype=float)
        if self.y is None or self.t is None:
            self.y, self.t, self.r_prev = r.copy(), float(t), r
            return self.y, None
        dt = float(t) - self.t
        if not dt > 0.0:
            return self.y, None
        w_in = (r - self.r_prev) / dt
        excess = None
        over = np.flatnonzero(np.abs(w_in) > self.margin * self.R1)
        if over.size:
            k = int(over[0])
            excess = (
                f"reference[{k}] changes at {w_in[k]:.4g} m/s^2, beyond the design rate "
                f"{self.R1[k]:.4g} m/s^2 x margin {self.margin:g}"
            )
        elif self.w_in is not None:
            jump = np.abs(w_in - self.w_in)
            allowed = self.margin * 2.0 * self.R2 * (dt + self.T)
            over = np.flatnonzero(jump > allowed)
            if over.size:
                k = int(over[0])
                excess = (
                    f"reference[{k}] slope changed by {jump[k]:.4g} m/s^2 in {dt:.4g} s, "
                    f"beyond the design acceleration {self.R2[k]:.4g} m/s^3 x margin "
                    f"{self.margin:g} (allowed {allowed[k]:.4g} m/s^2)"
                )
        band = self.R2 * (self.T + dt)  # slope tolerance around the smooth rate
        step = self.R2 * dt  # change of the smooth rate per message
        w_des = (r - self.y) / dt
        if np.all(np.abs(w_des) <= self.R1) and np.all(np.abs(w_des - self.wc) <= step + band):
            y, w = r, w_des  # inside the envelope: followed exactly
        else:
            e0 = self.r_prev - self.y  # gap before this message
            catch = np.sign(e0) * np.minimum(np.abs(e0) / dt, np.sqrt(2.0 * self.R2 * np.abs(e0)))
            w = np.clip(
                np.clip(w_in, -self.R1, self.R1) + catch,
                self.wc - step - band,
                self.wc + step + band,
            )
            w = np.clip(w, -self.R1, self.R1)
            y = self.y + w * dt
            self.limited += 1
        self.wc = self.wc + np.clip(w - self.wc, -step, step)
        self.y, self.w, self.t, self.r_prev, self.w_in = y, w, float(t), r, w_in
        return self.y, excess


def _nonfinite_message(t, x, v_d, u_e) -> str:
    bad = [
        name
        for name, a in (("t", np.atleast_1d(t)), ("x", x), ("v_d", v_d), ("u_e", u_e))
        if not np.all(np.isfinite(np.asarray(a, dtype=float)))
    ]
    return f"lpv law: non-finite input in {', '.join(bad) or 'inputs (overflow)'}"
