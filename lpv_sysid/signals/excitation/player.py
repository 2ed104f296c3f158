"""Excitation core: plays a signal set as velocity/yaw-rate reference and excitation u_e.

The core behind ``excitation_node`` (no ROS here). Given a table ``(t, u, names)``, a start
time and a scheduling offset it returns, at any time t,

* the body velocity reference ``v_ref`` (FRD, m/s, 3) = offset + enveloped channels,
* the yaw-rate reference ``r_ref`` (rad/s) = yaw offset + enveloped channel,
* the normalised excitation ``u_e`` (4, ``EXCITATION_NAMES`` order) = enveloped channels,

for the two experiments of seed 0:

* phase 1 (Sec. IV): offset = a vertex velocity of the box, channels ``u_ref, v_ref, w_ref,
  r_ref`` of the 4-axis multisine, no u_e (zeros);
* phase 2 (Sec. V): v_d(t) from ``u_d, v_d, w_d`` (no offset) and u_e(t) from
  ``ue_t, ue_a, ue_e, ue_r``.

Timeline (tau = t - start_time). A periodic table (multisines) plays
``[ramp_in | periods x T | ramp_out]``: the ramps are extra time on which the periodic signal
continues, so the central whole periods keep exact orthogonality; a non-periodic table (PRBS,
3-2-1-1) plays once with the ramps inside it. The envelope is a raised cosine
``(1 - cos(pi s / ramp)) / 2``. The offset is applied from t = -inf (trim) and stays after the
end; :meth:`abort` fades *everything* (signal and offset) from its current value to zero
within one ramp, starting at once (an abort time ahead of the last sample is clamped to it:
the fade never waits, and it never starts in the past either). Lookup is linear
interpolation with the index computed from the uniform grid in O(1) (no search). Time must
not go backwards: a sample older than the last one raises :class:`TimeOrderError` (a
stale/out-of-order message), a NaN time likewise; :class:`MonotonicTime` maps a clock that
may jump back (a node clock under ``use_sim_time``) onto a monotonic one for the core.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.signals.excitation.clock import TimeOrderError
from lpv_sysid.signals.store import validate_table

IDLE, RAMP_IN, RUNNING, RAMP_OUT, DONE, ABORTED = (
    "idle",
    "ramp_in",
    "running",
    "ramp_out",
    "done",
    "aborted",
)

PHASE1_CHANNELS = ("u_ref", "v_ref", "w_ref")
PHASE1_YAW_CHANNEL = "r_ref"
PHASE2_CHANNELS = ("u_d", "v_d", "w_d")
PHASE2_EXCITATION = ("ue_t", "ue_a", "ue_e", "ue_r")
#: default raised-cosine fade of phase 2 [s] (excitation node ``ramp_s``,
#: :meth:`ExcitationCore.phase2`), also the shortest fade the design envelope of
#: ``lpv-sysid synthesize`` allows for
DEFAULT_RAMP_S = 2.0


class ExcitationSample(NamedTuple):
    """One output of :meth:`ExcitationCore.sample` (a NamedTuple: cheap to build)."""

    t: float
    velocity: np.ndarray  # (3,) body velocity reference, FRD, m/s
    yaw_rate: float  # yaw-rate reference, FRD, rad/s
    u_e: np.ndarray  # (4,) normalised excitation, EXCITATION_NAMES order
    phase: str
    fraction: float  # progress in [0, 1] over the whole timeline


@dataclass(frozen=True)
class Progress:
    fraction: float
    phase: str


def _raised_cosine(s: float) -> float:
    """0 -> 1 over s in [0, 1]."""
    return 0.5 - 0.5 * math.cos(math.pi * s)


class ExcitationCore:
    """Table-lookup player with fade-in/out and abort (see module docstring)."""

    def __init__(
        self,
        t: np.ndarray,
        u: np.ndarray,
        names: Sequence[str],
        *,
        start_time: float,
        velocity_channels: Sequence[Optional[str]] = PHASE2_CHANNELS,
        yaw_rate_channel: Optional[str] = None,
        excitation_channels: Sequence[str] = (),
        offset: Sequence[float] = (0.0, 0.0, 0.0),
        yaw_rate_offset: float = 0.0,
        ramp: float = 1.0,
        periods: int = 1,
        periodic: bool = True,
    ):
        t, u, names = validate_table(t, u, names, where="excitation signals")
        self.names = names
        self.dt = float((t[-1] - t[0]) / (t.size - 1))
        self.rate = 1.0 / self.dt
        n = t.size

        def col(name: Optional[str]) -> np.ndarray:
            if name is None:
                return np.zeros(n)
            if name not in names:
                raise ConfigError(
                    f"excitation: channel {name!r} not in the signal set {list(names)}"
                )
            return u[:, names.index(name)]

        if len(velocity_channels) != 3:
            raise ConfigError(
                f"excitation: velocity_channels needs 3 entries, got {list(velocity_channels)}"
            )
        if len(excitation_channels) not in (0, 4):
            raise ConfigError(
                "excitation: excitation_channels needs 0 or 4 names, got "
                f"{list(excitation_channels)}"
            )
        cols = [col(c) for c in velocity_channels] + [col(yaw_rate_channel)]
        cols += [col(c) for c in excitation_channels] or [np.zeros(n)] * 4
        tab = np.stack(cols, axis=1)  # (N, 8): v(3), r, u_e(4)
        for name, v in (
            ("start_time", start_time),
            ("ramp", ramp),
            ("yaw_rate_offset", yaw_rate_offset),
        ):
            if not math.isfinite(v):
                raise ConfigError(f"excitation: {name} must be finite, got {v}")
        if ramp < 0:
            raise ConfigError(f"excitation: ramp must be >= 0, got {ramp}")
        if isinstance(periods, bool) or not isinstance(periods, int) or periods < 1:
            raise ConfigError(f"excitation: periods must be an integer >= 1, got {periods!r}")
        off = np.asarray(offset, dtype=float)
        if off.shape != (3,) or not np.all(np.isfinite(off)):
            raise ConfigError(f"excitation: offset must be 3 finite values, got {offset!r}")
        self.periodic = bool(periodic)
        if self.periodic:
            self.period = n * self.dt
            tab = np.vstack([tab, tab[:1]])  # wrap row: O(1) lookup of i + 1
            self.duration = periods * self.period + 2.0 * ramp
        else:
            self.period = (n - 1) * self.dt
            if periods != 1:
                raise ConfigError("excitation: periods > 1 needs a periodic table")
            if 2.0 * ramp > self.period:
                raise ConfigError(
                    f"excitation: two ramps of {ramp} s do not fit the {self.period} s signal"
                )
            tab = np.vstack([tab, tab[-1:]])
            self.duration = self.period
        self._tab = tab
        self._dtab = np.diff(tab, axis=0)
        self._rows = [tuple(r) for r in tab.tolist()]
        self._drows = [tuple(r) for r in self._dtab.tolist()]
        self._n = n
        self.start_time = float(start_time)
        self.ramp = float(ramp)
        self.offset = off
        self._offset_t = tuple(float(o) for o in off)
        self.yaw_rate_offset = float(yaw_rate_offset)
        self._last_t = -math.inf
        self._abort_t: Optional[float] = None
        self._abort_level = 0.0
        self._phase = IDLE
        self._fraction = 0.0

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def phase1(
        cls,
        t,
        u,
        names,
        *,
        start_time: float,
        vertex_velocity: Sequence[float],
        ramp: float = 0.0,
        yaw_rate_offset: float = 0.0,
    ) -> "ExcitationCore":
        """Phase 1 (seed 0 Sec. IV): vertex velocity + ``u_ref, v_ref, w_ref, r_ref``."""
        return cls(
            t,
            u,
            names,
            start_time=start_time,
            velocity_channels=PHASE1_CHANNELS,
            yaw_rate_channel=PHASE1_YAW_CHANNEL,
            offset=vertex_velocity,
            yaw_rate_offset=yaw_rate_offset,
            ramp=ramp,
        )

    @classmethod
    def phase2(
        cls,
        t,
        u,
        names,
        *,
        start_time: float,
        ramp: float = DEFAULT_RAMP_S,
        offset: Sequence[float] = (0.0, 0.0, 0.0),
        periodic: bool = True,
    ) -> "ExcitationCore":
        """Phase 2 (seed 0 Sec. V): v_d(t) from ``u_d, v_d, w_d``, u_e(t) from ``ue_*``.
        ``periodic=False``: a part of a period (fades inside it, no wrap-around)."""
        return cls(
            t,
            u,
            names,
            start_time=start_time,
            velocity_channels=PHASE2_CHANNELS,
            excitation_channels=PHASE2_EXCITATION,
            offset=offset,
            ramp=ramp,
            periodic=periodic,
        )

    @classmethod
    def from_file(cls, path: str, phase: str, *, start_time: float, **kwargs) -> "ExcitationCore":
        """Load ``signals.npz`` (:func:`lpv_sysid.signals.store.load_npz`) and build the
        ``phase`` ("phase1" or "phase2") core; ``kwargs`` go to :meth:`phase1`/:meth:`phase2`."""
        from lpv_sysid.signals.store import load_npz

        if phase not in ("phase1", "phase2"):
            raise ConfigError(f"excitation: phase must be 'phase1' or 'phase2', got {phase!r}")
        t, u, names = load_npz(path)
        return getattr(cls, phase)(t, u, names, start_time=start_time, **kwargs)

    # ------------------------------------------------------------------ state
    @property
    def end_time(self) -> float:
        """Time at which the excitation (not an abort) has faded out completely."""
        return self.start_time + self.duration

    @property
    def progress(self) -> Progress:
        return Progress(self._fraction, self._phase)

    def status(self) -> dict[str, str]:
        """Key/values for a diagnostic_msgs/DiagnosticStatus (strings only)."""
        remaining = (
            max(0.0, self.end_time - self._last_t)
            if math.isfinite(self._last_t)
            else self.duration
        )
        return {
            "phase": self._phase,
            "progress": f"{self._fraction:.4f}",
            "aborted": str(self.aborted).lower(),
            "start_time": f"{self.start_time:.3f}",
            "end_time": f"{self.end_time:.3f}",
            "remaining_s": f"{remaining:.3f}",
            "ramp_s": f"{self.ramp:.3f}",
            "channels": ",".join(self.names),
        }

    @property
    def aborted(self) -> bool:
        return self._abort_t is not None

    def abort(self, t: Optional[float] = None) -> float:
        """Fade everything (signal and offset) from its current value to zero within one
        ramp, starting now: at the last sample time. An abort time ``t`` ahead of it (a
        future stamp, a clock running ahead) is clamped to it, so the fade starts with the
        next sample instead of holding full amplitude until ``t``; a ``t`` before it (an old
        stamp) is clamped too, since what was output cannot be faded retroactively. Before any
        sample the output is zero at once. Idempotent; returns the effective abort time."""
        if self._abort_t is not None:
            return self._abort_t
        if not math.isfinite(self._last_t):
            # nothing has been output yet: there is nothing to fade, output zero from now on
            self._abort_level, self._abort_t, self._phase = 0.0, -math.inf, ABORTED
            return self._abort_t
        if t is not None and math.isnan(float(t)):
            raise TimeOrderError("excitation: abort time is NaN")
        t = self._last_t
        self._abort_level = self._envelope(t - self.start_time)[0]
        self._abort_t = t
        self._phase = ABORTED
        return t

    # ------------------------------------------------------------------ evaluation
    def _envelope(self, tau: float) -> tuple[float, str]:
        if tau < 0.0:
            return 0.0, IDLE
        if tau >= self.duration:
            return 0.0, DONE
        r = self.ramp
        if tau < r:
            return _raised_cosine(tau / r), RAMP_IN
        if tau > self.duration - r:
            return _raised_cosine((self.duration - tau) / r), RAMP_OUT
        return 1.0, RUNNING

    def sample(self, t: float) -> ExcitationSample:
        """Reference and excitation at time ``t`` (monotonic; see module docstring)."""
        t = float(t)
        if not t >= self._last_t:  # also catches NaN
            raise TimeOrderError(
                f"excitation: time {t} is before the last sample {self._last_t} "
                "(stale or out-of-order)"
            )
        self._last_t = t
        tau = t - self.start_time
        env, phase = self._envelope(tau)
        off_gain = 1.0
        if self._abort_t is not None:
            ta = t - self._abort_t
            if ta > 0.0 or (ta == 0.0 and self.ramp == 0.0):
                fade = 1.0 - _raised_cosine(ta / self.ramp) if ta < self.ramp else 0.0
                env = self._abort_level * fade
                off_gain = fade
            phase = ABORTED
        self._phase = phase
        self._fraction = (
            0.0 if tau <= 0.0 else (1.0 if tau >= self.duration else tau / self.duration)
        )
        # Hot path in plain floats (numpy calls on 8-vectors cost ~0.5 us each); the table
        # rows are tuples, so one lookup is an index computation and 8 multiply-adds.
        ox, oy, oz = self._offset_t
        if env > 0.0:
            x = ((tau - self.ramp) % self.period if self.periodic else tau) * self.rate
            i = int(x)
            if i >= self._n:  # round-off at the period end (x == n)
                i = self._n - 1
            w = x - i
            a = self._rows[i]
            d = self._drows[i]
            vel = np.array(
                (
                    (a[0] + w * d[0]) * env + off_gain * ox,
                    (a[1] + w * d[1]) * env + off_gain * oy,
                    (a[2] + w * d[2]) * env + off_gain * oz,
                )
            )
            yaw = (a[3] + w * d[3]) * env + off_gain * self.yaw_rate_offset
            ue = np.array(
                (
                    (a[4] + w * d[4]) * env,
                    (a[5] + w * d[5]) * env,
                    (a[6] + w * d[6]) * env,
                    (a[7] + w * d[7]) * env,
                )
            )
        else:
            vel = np.array((off_gain * ox, off_gain * oy, off_gain * oz))
            yaw = off_gain * self.yaw_rate_offset
            ue = np.zeros(4)
        return ExcitationSample(t, vel, yaw, ue, phase, self._fraction)

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised, stateless evaluation (no abort, no time-order check), for simulation:
        returns ``(velocity (K, 3), yaw_rate (K,), u_e (K, 4))`` at times ``t`` (K,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if not np.all(np.isfinite(t)):
            raise ConfigError("excitation.evaluate: times contain NaN or inf")
        tau = t - self.start_time
        r, D = self.ramp, self.duration
        env = np.where((tau >= 0) & (tau < D), 1.0, 0.0)
        if r > 0:
            env = np.where((tau >= 0) & (tau < r), 0.5 - 0.5 * np.cos(np.pi * tau / r), env)
            env = np.where(
                (tau > D - r) & (tau < D), 0.5 - 0.5 * np.cos(np.pi * (D - tau) / r), env
            )
        s = np.mod(tau - r, self.period) if self.periodic else np.clip(tau, 0.0, self.period)
        x = s * self.rate
        i = np.minimum(x.astype(int), self._n - 1)
        rows = (self._tab[i] + (x - i)[:, None] * self._dtab[i]) * env[:, None]
        v = rows[:, :3] + self.offset
        return v, rows[:, 3] + self.yaw_rate_offset, rows[:, 4:]
