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

Pure numpy, no allocation beyond a few small temporaries; see bench/bench_lpv_law.py.

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
from lpv_sysid.validation import is_finite_number


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
    """(K, x0, u0, R, Q, gamma, vmin, vmax) from io.formats.GainSchedule or synthesis.files.Gains."""
    K = np.asarray(schedule.K, dtype=float)
    x0 = np.asarray(schedule.x0, dtype=float)
    u0 = np.asarray(schedule.u0, dtype=float)
    if hasattr(schedule, "scheduling") and hasattr(schedule.scheduling, "min"):
        vmin, vmax = schedule.scheduling.min, schedule.scheduling.max
    else:
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

    ``schedule.feedforward`` is io.formats.FeedforwardSpec or the raw mapping (synthesis.files.Gains);
    state names from ``schedule.state_names`` (quadrotor layout when the schedule has none)."""
    F = getattr(schedule, "F_ff", None)
    spec = getattr(schedule, "feedforward", None)
    if F is None or spec is None:
        return None
    free = spec["free_states"] if isinstance(spec, dict) else spec.free_states
    names = getattr(schedule, "state_names", None)
    if not names:
        from lpv_sysid.models.quadrotor import STATE_NAMES as names
    names = list(names)
    rate = (spec.get("rate_states") or []) if isinstance(spec, dict) else spec.rate_states
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
    """The runtime law; ``schedule`` is a loaded gains file (io.formats.GainSchedule)."""

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
                    f"gain schedule: F_ff has shape {F.shape}, expected ({N}, {len(free) + m}, {p})"
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
        if mix is not None:
            mix = np.asarray(mix, dtype=float)
            if mix.shape != (m, m):
                raise ConfigError(f"mixer must be {m}x{m}, got {mix.shape}")
            self.mix = mix
            self.mix_inv = np.linalg.inv(mix)
        else:
            self.mix = self.mix_inv = None
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
        self.reset()

    def reset(self) -> None:
        self.t_prev: Optional[float] = None
        self.u_prev: Optional[np.ndarray] = None
        self.energy_z = 0.0  # monitor energies (windowed when monitor_window is set)
        self.energy_e = 0.0
        self.energy_e_total = 0.0  # running excitation energy (decides when to judge)
        self.bound_exceeded = False
        self.vd_filt: Optional[np.ndarray] = None  # low-passed v_d of the derivative filter
        self.a_filt = np.zeros(self.n_p)
        self.a_lp: Optional[np.ndarray] = None  # low-passed a (second stage, jerk)
        self.j_filt = np.zeros(self.n_p)

    def reference_rate(self, t: float, v_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Filtered first and second derivative (a, j) of the reference (module docstring, item 4);
        updates the filter. The jerk is the derivative filter (time constant ``ff_jerk_tau``)
        applied to a (two cascaded stages).

        Uses the time since the previous call of :meth:`step` (``t_prev``)."""
        if self.vd_filt is None or self.t_prev is None:
            self.vd_filt = np.array(v_d, dtype=float)
            self.a_filt = np.zeros(self.n_p)
            self.a_lp = np.zeros(self.n_p)
            self.j_filt = np.zeros(self.n_p)
            return self.a_filt, self.j_filt
        dt = t - self.t_prev
        if dt <= 0.0:
            return self.a_filt, self.j_filt
        k = 1.0 if self.tau == 0.0 else -math.expm1(-dt / self.tau)
        k2 = 1.0 if self.tau_j == 0.0 else -math.expm1(-dt / self.tau_j)
        # first-order low-pass + difference per axis on plain floats: for 3-vectors numpy's
        # per-call overhead (~1 us an operation) costs more than the arithmetic
        vf, alp = self.vd_filt.tolist(), self.a_lp.tolist()
        a_new, j_new, vf_new, alp_new = [], [], [], []
        for vdk, vfk, alk in zip(v_d.tolist(), vf, alp):
            y = vfk + k * (vdk - vfk)
            ak = (y - vfk) / dt
            y2 = alk + k2 * (ak - alk)
            a_new.append(ak)
            j_new.append((y2 - alk) / dt)
            vf_new.append(y)
            alp_new.append(y2)
        self.vd_filt = np.array(vf_new)
        self.a_lp = np.array(alp_new)
        self.a_filt = np.array(a_new)
        self.j_filt = np.array(j_new)
        return self.a_filt, self.j_filt

    # -- pieces (public for tests) -----------------------------------------------------
    def weights(self, v_d: np.ndarray) -> tuple[np.ndarray, bool]:
        """alpha(v_d) (clamped) and the clamp flag; box order of models.lpv.box_vertices."""
        t = ((v_d - self.vmin) * self.inv_range).tolist()
        clamped = False
        for k, tk in enumerate(t):
            if tk < 0.0 or tk > 1.0:
                clamped = True
                t[k] = 0.0 if tk < 0.0 else 1.0
        if self.n_p == 3:
            # unrolled kron((1-a, a), (1-b, b), (1-c, c)): plain floats are faster than 3 np.kron
            a, b, c = t
            a0, b0, c0 = 1.0 - a, 1.0 - b, 1.0 - c
            p00, p01, p10, p11 = a0 * b0, a0 * b, a * b0, a * b
            return np.array(
                (p00 * c0, p00 * c, p01 * c0, p01 * c, p10 * c0, p10 * c, p11 * c0, p11 * c)
            ), clamped
        alpha = np.ones(1)
        for tk in t:
            alpha = np.kron(alpha, np.array((1.0 - tk, tk)))
        return alpha, clamped

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
        filtered derivatives of v_d)."""
        if a is not None:
            a = np.asarray(a, dtype=float)
            if a.shape != (self.n_p,) or not np.all(np.isfinite(a)):
                raise SafetyError(
                    f"lpv law: reference acceleration must be {self.n_p} finite values, got {a}"
                )
        if j is not None:
            j = np.asarray(j, dtype=float)
            if j.shape != (self.n_p,) or not np.all(np.isfinite(j)):
                raise SafetyError(
                    f"lpv law: reference jerk must be {self.n_p} finite values, got {j}"
                )
        try:
            x = np.asarray(x, dtype=float)
            v_d = np.asarray(v_d, dtype=float)
            u_e = np.asarray(u_e, dtype=float)
            t = float(t)
        except (TypeError, ValueError) as exc:
            raise SafetyError(f"lpv law: non-numeric input ({exc})") from None
        if x.shape != (self.n_x,) or v_d.shape != (self.n_p,) or u_e.shape != (self.n_e,):
            raise SafetyError(
                f"lpv law: shapes x {x.shape}, v_d {v_d.shape}, u_e {u_e.shape}; expected "
                f"({self.n_x},), ({self.n_p},), ({self.n_e},)"
            )
        # one finiteness test for all inputs: a sum of squares is NaN/inf iff an entry is (or
        # overflows, which is also refused); ee is reused by the monitor
        ee = float(u_e @ u_e)
        if not math.isfinite(t + float(x @ x) + float(v_d @ v_d) + ee):
            raise SafetyError(_nonfinite_message(t, x, v_d, u_e))
        dt = 0.0
        if self.t_prev is not None:
            dt = t - self.t_prev
            if dt < 0.0:
                raise SafetyError(f"lpv law: time went backwards ({self.t_prev} -> {t})")
        a_filt = j_filt = None
        if self.has_ff and (a is None or (self.has_jerk and j is None)):
            # the derivative filter only runs when the caller does not supply a (and j)
            a_filt, j_filt = self.reference_rate(t, v_d)
        alpha, clamped = self.weights(v_d)
        row = alpha @ self.W
        mn, n, m = self._mn, self.n_x, self.n_u
        x_ref = row[mn : mn + n]
        u_ref = row[mn + n : mn + n + m]
        a_used = j_used = None
        if self.has_ff:
            a_used = a_filt if a is None else a
            j_used = (j_filt if j is None else j) if self.has_jerk else None
            aj = self._aj
            aj[: self.n_p] = a_used
            if j_used is not None:
                aj[self.n_p :] = j_used
            g = row[mn + n + m :].reshape(n + m, -1) @ aj
            x_ref = x_ref + g[:n]
            u_ref = u_ref + g[n:]
        u = u_ref + row[:mn].reshape(m, n) @ (x - x_ref) + self.R @ u_e
        saturated = False
        if self.mix is not None:
            u, saturated = self._saturate(u)
        rate_limited = False
        if self.rate is not None and self.u_prev is not None:
            du = u - self.u_prev
            if any(abs(d) > r * dt for d, r in zip(du.tolist(), self._rate_list)):
                step_max = self.rate * dt
                u = self.u_prev + np.clip(du, -step_max, step_max)
                rate_limited = True
                if self.mix is not None:
                    u, sat2 = self._saturate(u)
                    saturated = saturated or sat2
        self.u_prev = u
        self.t_prev = t
        # bound monitor (Eq. 18 performance output, Eq. 26/29 energies)
        if dt > 0.0:
            z = self.Qinv @ (x[self.vel] - v_d)
            if self.window is not None:
                lam = math.exp(-dt / self.window)
                self.energy_z *= lam
                self.energy_e *= lam
            self.energy_z += float(z @ z) * dt
            self.energy_e += ee * dt
            self.energy_e_total += ee * dt
        judged = self.energy_e_total >= self.cfg.monitor_min_energy and self.energy_e > 0.0
        if judged and self.energy_z > self.threshold * self.threshold * self.energy_e:
            self.bound_exceeded = True
        return u, {
            "clamped": clamped,
            "saturated": saturated,
            "rate_limited": rate_limited,
            "bound_judged": judged,
            "bound_exceeded": self.bound_exceeded,
            "feedforward": self.has_ff,
            "a_ff": a_used,
            "j_ff": j_used,
        }

    def _saturate(self, u: np.ndarray) -> tuple[np.ndarray, bool]:
        esc = self.mix_inv @ u
        lo, hi = self.cfg.u_esc_min, self.cfg.u_esc_max
        lst = esc.tolist()
        if min(lst) < lo or max(lst) > hi:
            return self.mix @ np.clip(esc, lo, hi), True
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
        if self.y is None:
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
