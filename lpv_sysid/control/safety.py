"""Safety supervisor: the conditions that end an experiment in a safe state.

Watches the inputs of the phase-2 loop (seed 0 Sec. 4: the LPV controller is only
certified inside the scheduling box and with fresh state feedback) and latches an abort
on the first of:

- ``stale``          an input stream older than its timeout: by receipt time, or by its
                     header stamp (a stamp frozen while messages keep arriving, or data
                     stamped long ago, ages like a silent stream; ``stamp_tolerance`` allows
                     for transport latency);
- ``future_stamp``   a header stamp ahead of the node clock by more than ``stamp_tolerance``;
- ``out_of_order``   a stream's header stamp going backwards;
- ``non_finite``     NaN/inf in any input value or stamp;
- ``out_of_box``     the scheduling vector v_d outside the box (plus a margin);
- ``bound_exceeded`` the bound monitor flag raised (state/excitation bounds);
- ``excitation_bound`` the excitation u_e beyond what the gains were designed for;
- ``reference_envelope`` the reference v_d changing faster than the gains were designed for;
- ``input_bound``    a physically absurd input (finite, but a broken or hostile sensor):
                     body speed, roll/pitch, body rate or a rotor speed outside its declared
                     bound (``max_body_speed``, ``max_tilt``, ``max_body_rate``,
                     ``max_rotor_speed``; rotor speeds are magnitudes, never negative);
- ``loop_delay``     the loop delay -- the age of the state a command is computed from (its
                     header stamp to the command's time) -- above the certified bound
                     ``loop_delay_bound`` on every command for ``loop_delay_tolerance`` or
                     longer (:meth:`SafetySupervisor.check_loop_delay`): the certificate proves
                     stability for delays up to the bound only, and a sustained delay below the
                     staleness timeouts (tens of ms) can already be past it;
- ``external``       an operator or another node asked for an abort.

Stamps and ``t_now`` must come from the same clock source: the shells pass the node clock,
which is the simulation time under ``use_sim_time`` and the system (wall) time otherwise,
and every publisher of the graph stamps with its node clock (``io/messages``); a stamp
from another clock source (e.g. wall time against sim time) is refused as stale or from
the future, never silently accepted.

:func:`check_closed_loop` is the start-up re-check of the gains against the certified
systems (eigenvalues of ``A_ij + B_ij K_i``, no LMI).

Once aborted, :attr:`action` is the safe state: excitation off and no actuator command
(the bridge then stops offboard streaming so PX4 takes control back: the hand-back of
docs/px4_transport.md, "Offboard safety path"). The abort stays latched until
:meth:`reset` is called while disarmed.
The supervisor is pure: it never reads a clock; every call carries its time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError, SafetyError

STALE = "stale"
OUT_OF_ORDER = "out_of_order"
NON_FINITE = "non_finite"
OUT_OF_BOX = "out_of_box"
BOUND_EXCEEDED = "bound_exceeded"
EXTERNAL = "external"
FUTURE_STAMP = "future_stamp"
EXCITATION_BOUND = "excitation_bound"
REFERENCE_ENVELOPE = "reference_envelope"
INPUT_BOUND = "input_bound"
LOOP_DELAY = "loop_delay"
REASONS = (
    STALE,
    OUT_OF_ORDER,
    NON_FINITE,
    OUT_OF_BOX,
    BOUND_EXCEEDED,
    EXTERNAL,
    FUTURE_STAMP,
    EXCITATION_BOUND,
    REFERENCE_ENVELOPE,
    INPUT_BOUND,
    LOOP_DELAY,
)


@dataclass(frozen=True)
class SafetyConfig:
    """Stream timeouts [s], the tolerance of header stamps against the node clock [s] and
    the scheduling box (seed 0 Eq. 17, ``v_d`` in a box), checked on every construction.
    The upper bounds keep the checks guards (the node's parameters declare the same)."""

    timeouts: Mapping[str, float] = cf.table(
        doc="stream -> abort when its newest sample is older [s]; (0, 1] s: the law of "
        "seed 0 Sec. 4 needs fresh state feedback, a longer timeout is no staleness check",
        item=cf.FieldSpec(cf.NUMBER, lo=0.0, lo_open=True, hi=1.0, unit=" s"),
    )
    box_min: tuple[float, ...] = cf.numbers((), "scheduling box low corner [m/s]")
    box_max: tuple[float, ...] = cf.numbers((), "scheduling box high corner [m/s]")
    box_margin: float = cf.number(
        0.0,
        "tolerance around the box [m/s]; at most 1 m/s: a wider margin leaves the certified "
        "box (Eq. 20) unguarded",
        lo=0.0,
        hi=1.0,
        unit=" m/s",
    )
    stamp_tolerance: float = cf.number(
        0.0,
        "header stamps may lead the node clock by this much (transport latency) [s]; at most "
        "0.5 s",
        lo=0.0,
        hi=0.5,
        unit=" s",
    )
    loop_delay_bound: float = cf.number(
        0.0,
        "the certified loop delay [s]: commands computed from states older than this (header "
        "stamp to command time) for loop_delay_tolerance or longer abort; 0: no bound (off)",
        lo=0.0,
        hi=1.0,
        unit=" s",
    )
    loop_delay_tolerance: float = cf.number(
        0.0,
        "how long the loop delay may stay above loop_delay_bound before the abort [s] "
        "(0: the first command above it)",
        lo=0.0,
        hi=1.0,
        unit=" s",
    )

    max_body_speed: float = cf.number(
        30.0,
        "|body velocity| beyond this is an absurd state sample -> abort [m/s]; 1 .. 100 m/s",
        lo=1.0,
        hi=100.0,
        unit=" m/s",
    )
    max_tilt: float = cf.number(
        1.2,
        "|roll| or |pitch| beyond this -> abort [rad]; 0.1 .. 1.5 rad (the law is linearised "
        "about level flight, seed 0 Eq. 14)",
        lo=0.1,
        hi=1.5,
        unit=" rad",
    )
    max_body_rate: float = cf.number(
        20.0, "|p|, |q| or |r| beyond this -> abort [rad/s]; 1 .. 100", lo=1.0, hi=100.0
    )
    max_rotor_speed: float = cf.number(
        5000.0,
        "a rotor speed outside [0, this] -> abort [rad/s]; 10 .. 1e5 (rotor speeds are "
        "magnitudes, seed 0 Eq. 8)",
        lo=10.0,
        hi=1e5,
    )

    def __post_init__(self):
        """The declared fields, then: box_min and box_max of one length, low below high."""
        cf.normalize_fields(self, "safety")
        if len(self.box_min) != len(self.box_max):
            raise cf.error(
                "safety",
                "box_min",
                f"{len(self.box_min)} values, box_max has {len(self.box_max)}",
            )
        if not all(a < b for a, b in zip(self.box_min, self.box_max)):
            raise cf.error("safety", "box_min", "must be below box_max")

    @classmethod
    def from_dict(cls, d: Mapping, where: str = "safety") -> "SafetyConfig":
        return cls(**cf.parse_fields(cls, d, where))


@dataclass(frozen=True)
class SafetyEvent:
    """A latched abort: when, why (one of :data:`REASONS`) and what exactly."""

    t: float
    reason: str
    detail: str

    def as_error(self) -> SafetyError:
        return SafetyError(f"safety abort at t={self.t:.6f} s: {self.reason}: {self.detail}")


@dataclass(frozen=True)
class SafeAction:
    """What the shells must do: publish excitation? publish actuator commands?"""

    excitation_on: bool
    commanding: bool


_RUN = SafeAction(excitation_on=True, commanding=True)
_SAFE = SafeAction(excitation_on=False, commanding=False)


@dataclass
class SafetySupervisor:
    config: SafetyConfig
    armed: bool = False
    event: SafetyEvent | None = None
    _t_arm: float = 0.0
    _last_rx: dict = field(default_factory=dict)
    _last_stamp: dict = field(default_factory=dict)
    _delay_since: float | None = None  # command time of the first of a run above the bound

    # -- state ------------------------------------------------------------------------
    @property
    def aborted(self) -> bool:
        return self.event is not None

    @property
    def action(self) -> SafeAction:
        """Safe state once aborted or before arming; run otherwise."""
        return _RUN if self.armed and not self.aborted else _SAFE

    def arm(self, t: float) -> None:
        """Start monitoring at time ``t``; every stream must arrive within its timeout."""
        if self.event is not None:  # aborted
            raise self.event.as_error()
        self.armed = True
        self._t_arm = float(t)
        self._last_rx.clear()
        self._delay_since = None

    def disarm(self) -> None:
        self.armed = False

    def reset(self) -> None:
        """Clear a latched abort (only while disarmed, i.e. on the ground / PX4 in charge)."""
        if self.armed:
            raise SafetyError("safety: cannot reset a latched abort while armed; disarm first")
        self.event = None
        self._last_stamp.clear()
        self._last_rx.clear()
        self._delay_since = None

    def abort(self, t: float, reason: str, detail: str) -> SafetyEvent:
        """Latch an abort (the first one wins); return the latched event."""
        if reason not in REASONS:
            raise ValueError(f"unknown safety reason {reason!r}")
        if self.event is None:
            self.event = SafetyEvent(float(t), reason, detail)
        return self.event

    # -- inputs -----------------------------------------------------------------------
    def on_input(
        self, stream: str, stamp: float, values: Sequence[float] | np.ndarray, t_now: float
    ) -> SafetyEvent | None:
        """One message of ``stream`` stamped ``stamp`` received at ``t_now``."""
        vals = np.asarray(values, dtype=float)
        # fast path: a sum is finite only if every term is (an overflow to inf is re-checked)
        if not (math.isfinite(stamp) and math.isfinite(float(vals.sum()))) and not (
            math.isfinite(stamp) and np.all(np.isfinite(vals))
        ):
            bad = np.flatnonzero(~np.isfinite(vals)).tolist()
            what = f"indices {bad}" if bad else f"stamp {stamp!r}"
            return self.abort(t_now, NON_FINITE, f"{stream}: non-finite value at {what}")
        last = self._last_stamp.get(stream)
        if last is not None and stamp < last:
            return self.abort(
                t_now, OUT_OF_ORDER, f"{stream}: stamp {stamp:.6f} s before previous {last:.6f} s"
            )
        self._last_stamp[stream] = float(stamp)
        self._last_rx[stream] = float(t_now)
        if self.armed and stream in self.config.timeouts:
            tol = self.config.stamp_tolerance
            if stamp - t_now > tol:
                return self.abort(
                    t_now,
                    FUTURE_STAMP,
                    f"{stream}: stamp {stamp:.6f} s is {stamp - t_now:.3f} s ahead "
                    f"of the node clock {t_now:.6f} s (tolerance {tol:g} s; same "
                    "clock source? use_sim_time on every node or on none)",
                )
            limit = self.config.timeouts[stream] + tol
            if t_now - stamp > limit:
                age = t_now - stamp
                what = (
                    f"stamp frozen at {stamp:.6f} s for {age:.3f} s while messages keep arriving"
                    if last == stamp
                    else f"stamp {age:.3f} s old at receipt"
                )
                return self.abort(
                    t_now,
                    STALE,
                    f"{stream}: {what} (timeout "
                    f"{self.config.timeouts[stream]:g} s + tolerance {tol:g} s)",
                )
        return self.event

    def check_scheduling(self, t: float, v_d: Sequence[float] | np.ndarray) -> SafetyEvent | None:
        """Abort when ``v_d`` leaves the box widened by ``box_margin``."""
        cfg = self.config
        if not cfg.box_min:
            return self.event
        v = [float(c) for c in v_d]
        if len(v) != len(cfg.box_min):
            return self.abort(
                t,
                NON_FINITE,
                f"scheduling vector has {len(v)} entries, expected {len(cfg.box_min)}",
            )
        if not all(math.isfinite(c) for c in v):
            return self.abort(t, NON_FINITE, f"scheduling vector {v} not finite")
        m = cfg.box_margin
        out = [i for i, c in enumerate(v) if c < cfg.box_min[i] - m or c > cfg.box_max[i] + m]
        if out:
            i = out[0]
            return self.abort(
                t,
                OUT_OF_BOX,
                f"scheduling[{i}] = {v[i]:.4g} outside "
                f"[{cfg.box_min[i]:.4g}, {cfg.box_max[i]:.4g}]"
                + (f" + margin {cfg.box_margin:g}" if cfg.box_margin else ""),
            )
        return self.event

    def check_state(self, t: float, x: Sequence[float] | np.ndarray) -> SafetyEvent | None:
        """Abort on an absurd state sample ``x = [phi, theta, u, v, w, p, q, r]`` (FRD, the
        controller's state topic): roll/pitch beyond ``max_tilt``, body speed beyond
        ``max_body_speed``, a body rate beyond ``max_body_rate``."""
        cfg = self.config
        phi, theta, u, v, w = float(x[0]), float(x[1]), float(x[2]), float(x[3]), float(x[4])
        if abs(phi) > cfg.max_tilt or abs(theta) > cfg.max_tilt:
            return self.abort(
                t,
                INPUT_BOUND,
                f"state: roll {phi:.4g} rad / pitch {theta:.4g} rad beyond max_tilt "
                f"{cfg.max_tilt:g} rad",
            )
        speed = math.sqrt(u * u + v * v + w * w)
        if speed > cfg.max_body_speed:
            return self.abort(
                t,
                INPUT_BOUND,
                f"state: body speed {speed:.4g} m/s beyond max_body_speed "
                f"{cfg.max_body_speed:g} m/s",
            )
        rate = max(abs(float(x[5])), abs(float(x[6])), abs(float(x[7])))
        if rate > cfg.max_body_rate:
            return self.abort(
                t,
                INPUT_BOUND,
                f"state: body rate {rate:.4g} rad/s beyond max_body_rate "
                f"{cfg.max_body_rate:g} rad/s",
            )
        return self.event

    def check_rotors(self, t: float, omega: Sequence[float] | np.ndarray) -> SafetyEvent | None:
        """Abort on a rotor speed outside ``[0, max_rotor_speed]`` (rad/s)."""
        hi = self.config.max_rotor_speed
        for k, w in enumerate(omega):
            if not 0.0 <= float(w) <= hi:
                return self.abort(
                    t,
                    INPUT_BOUND,
                    f"rotor_speeds[{k}] = {float(w):.4g} rad/s outside [0, {hi:g}] "
                    "(max_rotor_speed)",
                )
        return self.event

    def on_bound_flag(self, t: float, exceeded: bool, detail: str = "") -> SafetyEvent | None:
        """The bound monitor's verdict (True = a bound is exceeded)."""
        if exceeded:
            return self.abort(t, BOUND_EXCEEDED, detail or "bound monitor flag raised")
        return self.event

    def check(self, t_now: float) -> SafetyEvent | None:
        """Staleness of every configured stream at ``t_now`` (only while armed)."""
        if not self.armed or self.aborted:
            return self.event
        tol = self.config.stamp_tolerance
        for stream, timeout in self.config.timeouts.items():
            since = self._last_rx.get(stream, self._t_arm)
            age = t_now - since
            if age > timeout:
                if stream not in self._last_rx:
                    what = f"no message for {age:.3f} s since arming"
                else:
                    what = f"last message {age:.3f} s ago"
                return self.abort(t_now, STALE, f"{stream}: {what} (timeout {timeout:g} s)")
            # the data's own age: a stamp frozen while messages keep arriving ages too
            stamp = max(self._last_stamp.get(stream, self._t_arm), self._t_arm)
            if t_now - stamp > timeout + tol:
                return self.abort(
                    t_now,
                    STALE,
                    f"{stream}: newest stamp {stamp:.6f} s is {t_now - stamp:.3f} s "
                    f"old although messages arrive (stamp frozen or delayed; "
                    f"timeout {timeout:g} s + tolerance {tol:g} s)",
                )
        return self.event

    def check_loop_delay(self, t_command: float, t_state: float) -> SafetyEvent | None:
        """A command computed at ``t_command`` from the state stamped ``t_state`` (same clock):
        its loop delay ``t_command - t_state``. Abort (``loop_delay``) when the delay has been
        above ``loop_delay_bound`` on every command since one issued ``loop_delay_tolerance``
        or more earlier; a command at or below the bound ends the run. Off when the bound is 0
        or not armed."""
        bound = self.config.loop_delay_bound
        if bound <= 0.0 or not self.armed or self.event is not None:
            return self.event
        delay = t_command - t_state
        if not delay > bound:
            self._delay_since = None
            return None
        if self._delay_since is None:
            self._delay_since = float(t_command)
        above = t_command - self._delay_since
        if above >= self.config.loop_delay_tolerance:
            return self.abort(
                t_command,
                LOOP_DELAY,
                f"loop delay {1e3 * delay:.3f} ms (state stamp {t_state:.6f} s -> command "
                f"{t_command:.6f} s) above the certified {1e3 * bound:.3f} ms for "
                f"{1e3 * above:.3f} ms (tolerance {1e3 * self.config.loop_delay_tolerance:g} ms)",
            )
        return None

    def check_excitation(
        self, t: float, u_e: Sequence[float] | np.ndarray, limit: Sequence[float] | np.ndarray
    ) -> SafetyEvent | None:
        """Abort when ``|u_e[k]| > limit[k]`` for a channel (the excitation the gains were
        designed for times the margin; the law applies ``R u_e``, seed 0 Eq. 31)."""
        u = np.abs(np.asarray(u_e, dtype=float))
        lim = np.asarray(limit, dtype=float)
        bad = np.flatnonzero(~(u <= lim))
        if bad.size:
            k = int(bad[0])
            value = float(np.asarray(u_e)[k])
            return self.abort(
                t,
                EXCITATION_BOUND,
                f"excitation[{k}] = {value:.4g} beyond the "
                f"designed bound {lim[k]:.4g} (design peak x margin)",
            )
        return self.event


def closed_loop_abscissa(
    K: np.ndarray, systems: Sequence[Sequence[tuple]]
) -> tuple[float, int, int]:
    """Largest real part of the eigenvalues of ``A_ij + B_ij K_i`` over every vertex i and
    certified system j (seed 0 Eq. 23 polytope; continuous time), with its (i, j)."""
    worst, where = -math.inf, (-1, -1)
    for i, (Ki, lst) in enumerate(zip(K, systems)):
        for j, (A, B) in enumerate(lst):
            a = float(np.max(np.linalg.eigvals(np.asarray(A) + np.asarray(B) @ Ki).real))
            if not a <= worst:
                worst, where = a, (i, j)
    return worst, where[0], where[1]


def check_closed_loop(
    K: np.ndarray, systems: Sequence[Sequence[tuple]], label: str = "gains"
) -> float:
    """ConfigError unless every ``A_ij + B_ij K_i`` is Hurwitz (the stability the Lemma 1
    certificate implies, Eq. 30, re-checked by eigenvalues only: N x M_i eigenproblems of
    size n, e.g. 8 x 16 of 12 x 12 for the demo, milliseconds on a Raspberry Pi). Returns the
    worst spectral abscissa."""
    K = np.asarray(K, dtype=float)
    if len(systems) != K.shape[0]:
        raise ConfigError(
            f"{label}: {len(systems)} certified vertex system sets for {K.shape[0]} gains"
        )
    worst, i, j = closed_loop_abscissa(K, systems)
    if not worst < 0.0:
        raise ConfigError(
            f"{label}: closed loop A + B K unstable at vertex {i}, certified "
            f"system {j} (max Re(eig) = {worst:.4g} >= 0): the gains are not the "
            "certified ones or do not stabilise the certified models; refusing to "
            "fly them"
        )
    return worst


def loop_delay_s(
    tick_source: str, rate_hz: float, state_rate_hz: float, input_latency_s: float
) -> float:
    """Worst age of the state a command acts on, plus the time it is held, for the configured
    loop [s]: ``input_latency_s`` (p99 delivery latency of the inputs) + ``1 / state_rate_hz``
    (the newest sample is at most one period old / the command is held until the next state
    sample) + ``1 / rate_hz`` when the law steps on its own timer (``tick_source: timer``)."""
    from lpv_sysid.synthesis.delay import configured_delay_s

    if tick_source == "state":
        return float(input_latency_s + 1.0 / state_rate_hz)
    return configured_delay_s(rate_hz, state_rate_hz, input_latency_s)


def check_loop_delay(certificate, delay_s: float, label: str = "gains") -> str:
    """ConfigError when the configured loop delay ``delay_s`` exceeds the certificate's
    ``loop_delay.bound_s`` (issue 20 item 7: the H-inf proof covers constant delays up to that
    bound only); returns the info line. A certificate that claims a Lemma 1 proof but was
    written before the bound existed (no ``loop_delay``) is refused too: its proof says nothing
    about the loop it would fly (issue 20 round 2). Only a test law that claims no proof at all
    (``certificate.lmi`` starting with ``none``) flies without a bound, and the line says so."""
    bound = certificate.loop_delay_bound_s
    if bound is None:
        if str(getattr(certificate, "lmi", "")).strip().lower().startswith("none"):
            return (
                f"loop delay {delay_s * 1e3:.1f} ms NOT covered: {label} is a test law "
                "without a proof (certificate.lmi: none) and states no certificate.loop_delay"
            )
        raise ConfigError(
            f"{label}: certificate.loop_delay missing: these gains were certified before the "
            "loop delay was part of the proof, so the H-inf bound is not proven for the "
            f"configured loop ({delay_s * 1e3:.1f} ms); refusing to fly. Synthesize them again "
            "(the synthesis records certificate.loop_delay) and verify them with the "
            "configured loop delay"
        )
    if not delay_s <= bound:
        raise ConfigError(
            f"{label}: the configured loop delay {delay_s * 1e3:.1f} ms (input latency + state "
            f"period + command period) exceeds certificate.loop_delay.bound_s "
            f"{bound * 1e3:.1f} ms: the H-inf bound is not proven for this loop; refusing to "
            "fly (raise the loop rates, lower the transport latency, or synthesize gains "
            "certified for the delay)"
        )
    return f"loop delay {delay_s * 1e3:.1f} ms within the certified {bound * 1e3:.1f} ms"
