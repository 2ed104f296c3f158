"""Message-level behaviour of lpv_controller_node, shared with ``lpv-sysid replay``.

No rclpy here: the node shell forwards subscription messages and timer ticks to
:class:`ControllerRuntime`, and ``lpv-sysid replay`` does the same with the messages of a
bag (rosbags classes via ``MsgFactory.rosbags()``), so a replay computes exactly what the
node would have published. Both build :class:`ControllerSettings`, the one declaration of
the node's parameters (:mod:`lpv_sysid.nodes.parameters`: the rclpy declarations are
generated from it, and it validates every path the same way, cross-field rules included).

At construction (:func:`load_flight_schedule`), before any command can exist: the gains
file is validated (io/formats), the law it holds must hash to ``certificate.gains_sha256``
(the K that flies is the K that was certified), every ``A_ij + B_ij K_i`` of the certified
systems in the sidecar must be Hurwitz (eigenvalues only, milliseconds), the certificate
must carry the design envelope of the phase-2 signal, and the ESC limits must contain every
vertex trim; any failure refuses to start, naming the reason.

Per reference message: the reference v_d is passed through the design-envelope limiter
(:class:`~lpv_sysid.control.lpv_controller.ReferenceLimiter`, rate and acceleration of the
gains' designed v_d(t)) before scheduling and feedforward; an incoming reference beyond the
envelope x ``envelope_margin`` aborts. Per excitation message: ``kappa |u_e|`` beyond the
designed excitation peak x margin aborts.

Ticks (``tick_source``): ``timer`` steps the law every ``1 / rate_hz`` of the node clock on
the newest samples received; ``state`` steps it on each state sample at that sample's stamp
(:meth:`ControllerRuntime.on_input`), so the command is always computed on the freshest
state and carries its stamp -- the lock-stepped ``sim_vehicle`` of ``sim.launch.py`` waits for
exactly that command before it integrates on -- while the ``rate_hz`` timer only judges
staleness. Why: the demo gains lose stability at 8-12 ms of loop delay at 250 Hz (discrete
closed loop A + B K with the input delayed: spectral radius >= 1 from 2 samples on the worst
of the 128 certified systems, from 3 on the nominal vertex model), and
the wall-clock Python graph on a loaded 2-core machine measured ~14 ms mean loop delay
(state delivery p99 31 ms): it oscillated into saturation within 0.3 s.

Timeouts follow a declared rule (:meth:`ControllerSettings.validate`): every stream's
``timeout >= TIMEOUT_PERIODS / <stream>_rate_hz + input_latency_s`` (the publication rate and
the p99 delivery latency measured on the machine), so a healthy stream never aborts on its
own jitter.

Per tick, once started: staleness of every input stream (receipt time and
header stamp against the node clock), scheduling box, the runtime LPV law
u = u0(v_d) + K(v_d)(x - x0(v_d)) + R kappa u_e (seed 0 Eq. 31, control/lpv_controller.py;
with the reference feedforward of gains.yaml F_ff/F_jerk the law's own filtered derivatives
of the limited v_d supply a = dv_d/dt and its rate) on x = [phi, theta, u, v, w, p, q, r,
Mix Omega] (seed 0 Eq. 14 without position and yaw; delta = Mix Omega, Eq. 7), and its bound
monitor. Any fault (stale / frozen / future-stamped / out-of-order / non-finite input, v_d
outside the box or its envelope, excitation too large, bound exceeded, abort request)
latches an abort in :class:`~lpv_sysid.control.safety.SafetySupervisor`: one ERROR status
naming the reason is published and no actuator command follows, so the bridge hands control
back to PX4 (and the excitation node fades out on that status).

Log lines of the core (the abort, refused inputs, the start-up checks) are queued and
handed to the shell by :meth:`ControllerRuntime.take_log`: the node logs them with its own
logger (timestamped, on /rosout), the replay with Python logging.
"""

from __future__ import annotations

import gc
import logging
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from lpv_sysid.control.lpv_controller import LpvController, LpvControllerConfig, ReferenceLimiter
from lpv_sysid.control.safety import (
    EXTERNAL,
    NON_FINITE,
    OUT_OF_ORDER,
    REFERENCE_ENVELOPE,
    SafetyConfig,
    SafetySupervisor,
    check_closed_loop,
)
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.io import messages as M
from lpv_sysid.io.formats import GainSchedule, load_certified_systems
from lpv_sysid.models.quadrotor import mixer
from lpv_sysid.nodes import parameters as P

LOG = logging.getLogger(__name__)

INPUT_TOPICS = ("state", "rotor_speeds", "velocity_reference", "excitation")
OUTPUT_TOPICS = ("actuator_command", "status")
_TIMEOUTS = ("state_timeout_s", "rotor_timeout_s", "reference_timeout_s", "excitation_timeout_s")
#: timeout parameter -> the parameter holding its stream's publication rate (the timeout rule)
_RATES = {
    "state_timeout_s": "state_rate_hz",
    "rotor_timeout_s": "rotor_rate_hz",
    "reference_timeout_s": "reference_rate_hz",
    "excitation_timeout_s": "excitation_rate_hz",
}
#: the timeout rule: ``timeout >= TIMEOUT_PERIODS / rate + input_latency_s``. At any check the
#: newest sample of a healthy stream is at most one period old plus its delivery latency; one
#: lost sample (the sensor streams are best effort) makes it two periods
TIMEOUT_PERIODS = 2
#: ``reference_hold``: how the law sees the reference between messages
REFERENCE_HOLDS = ("foh", "zoh")
#: ``tick_source``: ``timer`` (a law step every 1 / rate_hz of the node clock on the newest
#: samples received) or ``state`` (a law step per state sample, at its stamp)
TICK_SOURCES = ("timer", "state")
#: the scheduling-box margin may absorb round-off and the limiter's one-step overshoot, not
#: widen the certified box: at most this fraction of its narrowest axis
BOX_MARGIN_MAX_FRACTION = 0.1


@dataclass(frozen=True)
class ControllerSettings(P.Settings):
    """The node's parameters (config/lpv_controller.yaml): the one declaration."""

    WHERE = "lpv_controller"

    gains_file: str = P.text(
        "",
        "gains.yaml from `lpv-sysid synthesize` (validated, hash, "
        "closed-loop stability and design envelope checked at start)",
        nonempty=True,
    )
    models_file: str = P.text("", "vertex_models.yaml the gains must match (optional)")
    rate_hz: float = P.double(250.0, "actuator command rate [Hz]", 1.0, 2000.0)
    state_timeout_s: float = P.double(0.02, "state older than this -> abort [s]", 0.001, 1.0)
    rotor_timeout_s: float = P.double(
        0.05, "rotor_speeds older than this -> abort [s]", 0.001, 1.0
    )
    reference_timeout_s: float = P.double(
        0.1, "velocity_reference older than this -> abort [s]", 0.001, 1.0
    )
    excitation_timeout_s: float = P.double(
        0.1, "excitation older than this -> abort [s]", 0.001, 1.0
    )
    stamp_tolerance_s: float = P.double(
        0.01,
        "header stamps may lead the node clock, or lag it beyond a stream's timeout, "
        "by this much (transport latency) [s]; node clock = sim time under use_sim_time",
        0.0,
        0.5,
    )
    tick_source: str = P.text(
        "timer",
        "timer: a law step every 1 / rate_hz of the node clock, on the newest samples "
        "received; state: a law step on each state sample, at its stamp (the freshest sample, "
        "no tick phase; the lock-stepped sim_vehicle waits for exactly that command), the "
        "timer then only judges staleness",
        choices=TICK_SOURCES,
    )
    reference_hold: str = P.text(
        "zoh",
        "the reference between its messages: zoh holds it (a staircase: its steps reach "
        "the feedforward's derivative filter), foh extrapolates the last limited value along "
        "its slope (the played table is piecewise linear; at most reference_timeout_s ahead)",
        choices=REFERENCE_HOLDS,
    )
    state_rate_hz: float = P.double(
        250.0, "publication rate of state [Hz] (timeout rule)", 1.0, 5000.0
    )
    rotor_rate_hz: float = P.double(
        100.0, "publication rate of rotor_speeds [Hz] (timeout rule)", 1.0, 5000.0
    )
    reference_rate_hz: float = P.double(
        100.0, "publication rate of velocity_reference [Hz] (timeout rule)", 1.0, 5000.0
    )
    excitation_rate_hz: float = P.double(
        100.0, "publication rate of excitation [Hz] (timeout rule)", 1.0, 5000.0
    )
    input_latency_s: float = P.double(
        0.0,
        "p99 of receipt time minus header stamp of the input streams, measured on the "
        f"target machine (config/lpv_controller.yaml: this machine's) [s]; every timeout >= "
        f"{TIMEOUT_PERIODS} / rate + this",
        0.0,
        1.0,
    )
    box_margin: float = P.double(
        0.0,
        "tolerance around the scheduling box [m/s] (at most "
        f"{BOX_MARGIN_MAX_FRACTION:g} of its narrowest axis)",
        0.0,
        1.0,
    )
    excitation_gain: float = P.double(
        1.0, "excitation multiplier kappa (seed 0 Eq. 33)", 0.0, 10.0
    )
    arm_length: float = P.double(0.225, "arm length of the mixer (seed 0 Eq. 7) [m]", 0.01, 10.0)
    u_esc_min: float = P.double(
        0.0, "lower ESC command limit (< u_esc_max, below every vertex trim)", 0.0, 1.0
    )
    u_esc_max: float = P.double(
        1.0, "upper ESC command limit (> u_esc_min, above every vertex trim)", 0.0, 1.0
    )
    rate_limit: tuple = P.doubles(
        (),
        "per-channel rate limit of u [1/s] (unset: none)",
        lo=0.0,
        hi=1000.0,
        lengths=(0, 4),
        lo_open=True,
    )
    monitor_margin: float = P.double(
        1.2, "bound monitor: abort when gain > gamma x margin", 1.0, 10.0
    )
    monitor_min_energy: float = P.double(
        0.05,
        "bound monitor: ||u_e||^2 before judging (the design signal has 1 per period, Eq. 26)",
        1e-6,
        1.0,
    )
    monitor_window_s: float = P.double(
        0.0,
        "> 0: exponentially forgetting monitor window [s] (>= 1 s); 0: running from start",
        0.0,
        1e4,
    )
    feedforward: bool = P.flag(True, "reference feedforward when gains.yaml has F_ff")
    ff_filter_tau: float = P.double(
        0.05, "derivative filter of velocity_reference (a) [s]", 0.0, 2.0
    )
    ff_jerk_tau: float = P.double(
        0.2, "jerk stage of the derivative filter (F_jerk) [s]", 0.0, 5.0
    )
    envelope_margin: float = P.double(
        1.5,
        "abort when the reference rate/acceleration or kappa u_e exceed the gains' design "
        "envelope (certificate.design) by this factor",
        1.0,
        10.0,
    )
    auto_start: bool = P.flag(False, "start commanding without the service")
    status_rate_hz: float = P.double(2.0, "status publication rate [Hz]", 0.1, 100.0)

    def validate(self) -> None:
        if not self.u_esc_min < self.u_esc_max:
            self.fail(f"need u_esc_min < u_esc_max, got {self.u_esc_min:g} >= {self.u_esc_max:g}")
        period = 1.0 / self.rate_hz
        for name in _TIMEOUTS:
            if getattr(self, name) < period:
                self.fail(
                    f"{name} {getattr(self, name):g} s is shorter than one control period "
                    f"(1 / rate_hz = {period:g} s): staleness cannot be judged that finely"
                )
            rate = _RATES[name]
            least = self.min_timeout(name)
            if getattr(self, name) < least - 1e-12:
                self.fail(
                    f"{name} {getattr(self, name):g} s is below {TIMEOUT_PERIODS} / {rate} + "
                    f"input_latency_s = {TIMEOUT_PERIODS} / {getattr(self, rate):g} Hz + "
                    f"{self.input_latency_s:g} s = {least:.4g} s: a healthy stream would "
                    "abort on its own delivery jitter"
                )
        shortest = min(getattr(self, n) for n in _TIMEOUTS)
        if self.stamp_tolerance_s > shortest:
            self.fail(
                f"stamp_tolerance_s {self.stamp_tolerance_s:g} s exceeds the shortest "
                f"timeout {shortest:g} s (stale data would pass)"
            )
        if self.stamp_tolerance_s < 1.0 / self.state_rate_hz - 1e-12:
            self.fail(
                f"stamp_tolerance_s {self.stamp_tolerance_s:g} s is below one state period "
                f"(1 / state_rate_hz = {1.0 / self.state_rate_hz:g} s): under use_sim_time "
                "a sample may arrive before the /clock message of its instant"
            )
        if 0.0 < self.monitor_window_s < 1.0:
            self.fail(
                f"monitor_window_s must be 0 (running) or >= 1 s, got {self.monitor_window_s:g}"
            )

    def min_timeout(self, name: str) -> float:
        """The least value the timeout rule allows for the timeout parameter ``name``."""
        return TIMEOUT_PERIODS / getattr(self, _RATES[name]) + self.input_latency_s

    @property
    def timeouts(self) -> dict:
        return {
            "state": self.state_timeout_s,
            "rotor_speeds": self.rotor_timeout_s,
            "velocity_reference": self.reference_timeout_s,
            "excitation": self.excitation_timeout_s,
        }

    def law_config(self) -> LpvControllerConfig:
        return LpvControllerConfig(
            u_esc_min=self.u_esc_min,
            u_esc_max=self.u_esc_max,
            rate_limit=self.rate_limit or None,
            monitor_margin=self.monitor_margin,
            monitor_min_energy=self.monitor_min_energy,
            feedforward=self.feedforward,
            ff_filter_tau=self.ff_filter_tau,
            ff_jerk_tau=self.ff_jerk_tau,
            monitor_window=self.monitor_window_s or None,
        )


def load_flight_schedule(
    settings: ControllerSettings, mix: np.ndarray
) -> tuple[GainSchedule, list]:
    """The gains to fly, after every start-up check of the module docstring; returns the
    schedule and the info lines describing what was checked. ConfigError names the reason."""
    path = settings.gains_file
    label = str(path)
    gs = GainSchedule.load(path, settings.models_file or None)
    gs.check_law_sha256(label)
    systems = load_certified_systems(
        path, gs.certificate, len(gs.state_names), len(gs.input_names), label
    )
    abscissa = check_closed_loop(gs.K, systems, label)
    design = gs.certificate.design
    if design is None:
        raise ConfigError(
            f"{label}: certificate.design missing: the gains do not say which "
            "phase-2 signal they were designed for (reference rates, excitation "
            "peak); re-run `lpv-sysid synthesize --summary <signals>/summary.yaml`"
        )
    m = gs.K.shape[1]
    if mix.shape != (m, m):
        raise ConfigError(f"{label}: {m} inputs, but the mixer is {mix.shape[0]}x{mix.shape[1]}")
    esc = np.linalg.solve(mix, gs.u0.T).T  # vertex trims as ESC commands (Eq. 7)
    lo, hi = settings.u_esc_min, settings.u_esc_max
    for i, e in enumerate(esc):
        if e.min() < lo or e.max() > hi:
            raise ConfigError(
                f"lpv_controller: ESC limits [{lo:g}, {hi:g}] do not contain the "
                f"trim ESC commands {np.round(e, 4).tolist()} of vertex {i} "
                f"({label}): every command would be clamped"
            )
    width = float(np.min(gs.scheduling.max - gs.scheduling.min))
    if settings.box_margin > BOX_MARGIN_MAX_FRACTION * width:
        raise ConfigError(
            f"lpv_controller: box_margin {settings.box_margin:g} m/s exceeds "
            f"{BOX_MARGIN_MAX_FRACTION:g} of the narrowest box axis ({width:g} m/s, "
            f"{label}): the certificate covers the box only"
        )
    n_sys = sum(len(s) for s in systems)
    info = [
        f"gains {path}: law sha256 {(gs.certificate.gains_sha256 or '')[:12]} matches the "
        f"certificate; closed loop stable on {n_sys} certified systems (max Re(eig) "
        f"{abscissa:.3g}); design envelope ({design.source or 'certificate.design'}): "
        f"|dv_d/dt| <= {np.round(design.reference_rate, 3).tolist()} m/s^2, |u_e| <= "
        f"{np.round(design.excitation_peak, 4).tolist()}"
    ]
    return gs, info


class CommandBuilder:
    """``actuator_command`` messages for the tick: the message of
    :func:`lpv_sysid.io.messages.actuator_command_msg` (``sensor_msgs/JointState``, the virtual
    channels ``INPUT_NAMES`` in ``position``) with the message classes looked up once.

    The command comes from the law, whose inputs are checked and whose output the mixer
    clips, so the per-message finiteness and duplicate-name checks of io.messages (5 of the
    7 us a message took) are not repeated; a stamp outside builtin_interfaces/Time goes
    through io.messages, which names the problem (test_nodes_controller compares both
    builders field by field)."""

    def __init__(self, factory: M.MsgFactory) -> None:
        self.f = factory
        self._time = factory.get("builtin_interfaces/msg/Time")
        self._header = factory.get("std_msgs/msg/Header")
        self._joint_state = factory.get("sensor_msgs/msg/JointState")
        self._names = [str(n) for n in M.INPUT_NAMES]
        self._seq = factory.float_seq

    def __call__(self, stamp_ns: int, u: np.ndarray) -> Any:
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        if not -(2**31) <= sec < 2**31:
            return M.actuator_command_msg(self.f, stamp_ns, u)  # raises MessageError
        seq = self._seq
        return self._joint_state(
            header=self._header(stamp=self._time(sec=sec, nanosec=nanosec), frame_id=""),
            name=list(self._names),
            position=seq(u),
            velocity=seq([]),
            effort=seq([]),
        )


def settle_gc() -> None:
    """The GC policy of a running controller (called by the node once the runtime is loaded).

    ``gc.collect()`` then ``gc.freeze()``: everything alive after loading (numpy, the message
    classes, the gains and certificate arrays, the parsed config: ~46,000 tracked objects with
    the stand-in rclpy, more with the real one) moves to the permanent generation, so a full
    collection -- CPython still triggers them when cyclic garbage accumulates, e.g. from the
    executor -- traverses only what was allocated since: measured 7 ms for a full collection
    of the loaded heap before, < 0.01 ms after, i.e. no longer a tick's worth of latency. The
    young-generation thresholds stay CPython's: reference counting frees everything a tick
    allocates (bench_controller_node counted no collection of any generation in 6,245 ticks
    and 13,750 input messages), so a young pass only runs on the executor's own garbage."""
    gc.collect()
    gc.freeze()


class ControllerRuntime:
    """See module docstring. ``factory`` builds the output messages (MsgFactory)."""

    def __init__(
        self,
        settings: ControllerSettings,
        factory: M.MsgFactory,
        name: str = "/lpv_sysid/lpv_controller",
    ):
        self.settings = settings
        self.f = factory
        self.name = name
        self._log: list[tuple[str, str]] = []
        self.mix = mixer(settings.arm_length)
        self.schedule, info = load_flight_schedule(settings, self.mix)
        self._log += [("info", line) for line in info]
        self.law = LpvController(self.schedule, settings.law_config(), mix=self.mix)
        design = self.schedule.certificate.design
        if design is None:  # load_flight_schedule refuses such gains; stated for the types
            raise ConfigError(f"{settings.gains_file}: certificate.design missing")
        self.limiter = ReferenceLimiter(
            design.reference_rate,
            design.reference_accel,
            design.knot_interval_s,
            settings.envelope_margin,
        )
        self.excitation_limit = np.asarray(design.excitation_peak) * settings.envelope_margin
        if self.excitation_limit.size != self.law.n_e:
            raise ConfigError(
                f"{settings.gains_file}: certificate.design.excitation_peak has "
                f"{self.excitation_limit.size} entries, R has {self.law.n_e} "
                "columns"
            )
        box = self.schedule.scheduling
        self.supervisor = SafetySupervisor(
            SafetyConfig(
                timeouts=settings.timeouts,
                box_min=tuple(box.min),
                box_max=tuple(box.max),
                box_margin=settings.box_margin,
                stamp_tolerance=settings.stamp_tolerance_s,
            )
        )
        self.x8: Optional[np.ndarray] = None  # phi, theta, u, v, w, p, q, r (FRD)
        self.omega: Optional[np.ndarray] = None  # rotor speeds (4), rad/s
        # the law's 12-state [x8; Mix Omega] (seed 0 Eq. 7, 14), kept up to date per sample so
        # a tick only reads it; kappa u_e likewise (computed once per excitation message)
        self._x12 = np.empty(len(M.INPUT_NAMES) + 8)
        self._ue_scaled: Optional[np.ndarray] = None
        self._vd_checked: Optional[np.ndarray] = None  # v_d_in the box check last passed
        self._command = CommandBuilder(factory)
        self.v_d_in: Optional[np.ndarray] = None  # velocity reference as received (3), FRD
        self.v_d: Optional[np.ndarray] = None  # the reference the law follows (envelope-limited)
        self.u_e: Optional[np.ndarray] = None  # normalised excitation (4)
        self._ref_stamp: Optional[float] = None
        self._t_sample: Optional[float] = None  # last state stamp ticked (tick_source: state)
        self._ref_slope: Optional[np.ndarray] = None  # slope of the limited reference
        self.commands = 0
        self.flags = {"clamped": 0, "saturated": 0, "rate_limited": 0}
        self._abort_reported = False

    # -- log lines for the shell ----------------------------------------------------------
    def take_log(self) -> list[tuple[str, str]]:
        """Queued ``(level, text)`` lines (level: info | warn | error), oldest first."""
        out, self._log = self._log, []
        return out

    # -- inputs -------------------------------------------------------------------------
    def on_message(self, topic: str, msg, t_now: float) -> float | None:
        """A message of ``topic`` (one of :data:`INPUT_TOPICS`) received at ``t_now`` [s];
        returns its header time, None when it was malformed."""
        try:
            t, values = parse_input(topic, msg)
        except M.MessageError as exc:
            self.on_bad_message(topic, exc, t_now)
            return None
        self.on_sample(topic, t, values, t_now)
        return t

    def on_input(self, topic: str, msg, t_now: float) -> list:
        """:meth:`on_message`, then what to publish: with ``tick_source: state`` a state
        sample newer than the last one ticked runs the law at its stamp (:meth:`tick`)."""
        t = self.on_message(topic, msg, t_now)
        return [] if t is None else self._after_sample(topic, t, t_now)

    def on_parsed_input(self, topic: str, t: float, values: np.ndarray, t_now: float) -> list:
        """:meth:`on_input` for an input already parsed (:func:`parse_inputs`, the replay)."""
        self.on_sample(topic, t, values, t_now)
        return self._after_sample(topic, t, t_now)

    def _after_sample(self, topic: str, t: float, t_now: float) -> list:
        if (
            self.settings.tick_source == "state"
            and topic == "state"
            and (self._t_sample is None or t > self._t_sample)
        ):
            self._t_sample = t
            return self.tick(t_now, t_sample=t)
        return []

    def on_timer(self, t_now: float) -> list:
        """The node's ``rate_hz`` timer: the law step (``tick_source: timer``) or only the
        staleness watch (``state``: a silent state stream must still abort)."""
        if self.settings.tick_source == "timer":
            return self.tick(t_now)
        return self.watchdog(t_now)

    def on_bad_message(self, topic: str, exc: Exception, t_now: float) -> None:
        if self.supervisor.armed:
            self.supervisor.abort(t_now, NON_FINITE, f"{topic}: {exc}")
        else:
            self._log.append(("warn", f"{topic} rejected before start: {exc}"))

    def on_sample(self, topic: str, t: float, values: np.ndarray, t_now: float) -> None:
        """Parsed input (see :func:`parse_input`): header time ``t`` [s], ``values``."""
        sup = self.supervisor
        sup.on_input(topic, t, values, t_now)
        if topic == "state":
            self.x8 = values
            self._x12[:8] = values
        elif topic == "rotor_speeds":
            self.omega = values
            self.mix.dot(values, out=self._x12[8:])  # delta = Mix Omega (Eq. 7)
        elif topic == "velocity_reference":
            self.v_d_in = values[:3]
            if sup.aborted:
                self.v_d = self.v_d_in
                return
            self._ref_stamp = t
            self.v_d, excess = self.limiter.update(t, self.v_d_in)
            self._ref_slope = self.limiter.w.copy()
            if excess is not None and sup.armed:
                sup.abort(t_now, REFERENCE_ENVELOPE, excess)
        else:
            self.u_e = values
            self._ue_scaled = self.settings.excitation_gain * values
            if sup.armed and not sup.aborted:
                sup.check_excitation(t_now, self._ue_scaled, self.excitation_limit)

    def missing_inputs(self) -> list:
        """The input streams of which no sample has arrived yet."""
        have = {
            "state": self.x8,
            "rotor_speeds": self.omega,
            "velocity_reference": self.v_d_in,
            "excitation": self.u_e,
        }
        return [topic for topic in INPUT_TOPICS if have[topic] is None]

    def start(self, t_now: float, wait_for_inputs: bool = False) -> tuple[bool, str]:
        """Arm at ``t_now``; ``(started, why)``. ``wait_for_inputs`` (the node): refused while
        a stream has not delivered its first sample -- arming then would latch a stale abort
        (measured under real Jazzy: the controller started the moment its service appeared,
        before discovery had matched the excitation node, and aborted 0.1 s later)."""
        sup = self.supervisor
        ev = sup.event
        if ev is not None:
            return False, f"aborted ({ev.reason}: {ev.detail}); restart the node"
        if sup.armed:
            return False, "already started"
        if not t_now > 0.0:
            return False, (
                f"node clock reads {t_now:g} s: under use_sim_time no /clock has "
                "arrived yet; start once the clock runs"
            )
        missing = self.missing_inputs() if wait_for_inputs else []
        if missing:
            return False, (
                f"no {', '.join(missing)} received yet: start once every input stream arrives"
            )
        sup.arm(t_now)
        self.law.reset()
        self.limiter.reset()
        if self.v_d_in is not None and self._ref_stamp is not None:
            # follow from the current reference, not a ramp to it
            self.v_d, _ = self.limiter.update(self._ref_stamp, self.v_d_in)
            self._ref_slope = self.limiter.w.copy()
        return True, "LPV control started"

    def abort(self, t_now: float, reason: str = "abort requested") -> str:
        ev = self.supervisor.abort(t_now, EXTERNAL, reason)
        return f"{ev.reason}: {ev.detail}"

    # -- output -------------------------------------------------------------------------
    def tick(self, t_now: float, t_sample: float | None = None) -> list:
        """``[(topic, msg), ...]`` to publish at ``t_now``: the command, or the abort status.

        Staleness is judged at the node clock ``t_now``; the law steps at ``t_sample`` (the
        stamp of the state sample the step is computed on, ``tick_source: state``; default
        ``t_now``), which also stamps the command."""
        sup = self.supervisor
        out: list[tuple[str, Any]] = []
        if not sup.armed:
            return out
        t_law = t_now if t_sample is None else float(t_sample)
        sup.check(t_now)
        if sup.aborted or self._ue_scaled is None or self.x8 is None or self.omega is None:
            return self._report_abort(t_now, out)
        if self.v_d is None or self.v_d_in is None:
            return self._report_abort(t_now, out)
        if self.v_d_in is not self._vd_checked:
            # the box check is a function of v_d_in alone: once per reference message
            sup.check_scheduling(t_now, self.v_d_in)
            if sup.aborted:
                return self._report_abort(t_now, out)
            self._vd_checked = self.v_d_in
        try:
            u, info = self.law.step(t_law, self._x12, self.reference_at(t_law), self._ue_scaled)
        except SafetyError as exc:
            kind = OUT_OF_ORDER if "backwards" in str(exc) else NON_FINITE
            sup.abort(t_now, kind, str(exc))
            return self._report_abort(t_now, out)
        flags = self.flags
        if info["clamped"]:
            flags["clamped"] += 1
        if info["saturated"]:
            flags["saturated"] += 1
        if info["rate_limited"]:
            flags["rate_limited"] += 1
        if info["bound_exceeded"]:
            sup.on_bound_flag(
                t_now,
                True,
                f"L2 gain estimate {self.law.gain():.4g} > gamma "
                f"{self.law.gamma:g} x margin "
                f"{self.settings.monitor_margin:g}",
            )
            return self._report_abort(t_now, out)
        self.commands += 1
        out.append(("actuator_command", self._command(round(t_law * 1e9), u)))
        return out

    def reference_at(self, t: float) -> np.ndarray:
        """The reference the law follows at ``t``: the limited v_d of the last message, with
        ``reference_hold: foh`` moved along its slope by ``t - stamp`` (clipped to one
        message period back, ``reference_timeout_s`` ahead). The excitation node plays a
        linearly interpolated table, so this reproduces it between messages; held (zoh) it
        is a staircase at the message rate whose steps the feedforward's derivative filter
        turns into spikes (offline, 250 Hz law on a 100 Hz reference, 34 s of the demo
        signal: 16 saturated commands with zoh, 0 with foh or an exact reference)."""
        v_d, slope, stamp = self.v_d, self._ref_slope, self._ref_stamp
        if v_d is None:
            raise SafetyError("lpv_controller: no velocity_reference received yet")
        if self.settings.reference_hold == "zoh" or slope is None or stamp is None:
            return v_d
        s = self.settings
        dt = min(max(t - stamp, -1.0 / s.reference_rate_hz), s.reference_timeout_s)
        return v_d + slope * dt

    def watchdog(self, t_now: float) -> list:
        """Staleness of every input at ``t_now`` without a law step: ``[]`` or, on the
        abort, its status (once)."""
        sup = self.supervisor
        if sup.armed:
            sup.check(t_now)
        return self._report_abort(t_now, [])

    def _report_abort(self, t_now: float, out: list) -> list:
        sup = self.supervisor
        ev = sup.event
        if ev is not None and sup.armed and not self._abort_reported:
            self._abort_reported = True
            self._log.append(
                ("error", f"safety abort: {ev.reason}: {ev.detail}; actuator commands stopped")
            )
            out.append(("status", self.status(t_now)))
        return out

    def status(self, t_now: float):
        sup = self.supervisor
        ev = sup.event
        if ev is not None:
            level, message = "ERROR", f"safety abort: {ev.reason}: {ev.detail}"
        elif sup.armed:
            level, message = "OK", "commanding"
        else:
            level, message = "OK", "waiting for start (not commanding)"
            missing = self.missing_inputs()
            if missing:
                message += f"; no {', '.join(missing)} received yet"
        values = {
            "armed": sup.armed,
            "aborted": sup.aborted,
            "commanding": sup.action.commanding,
            "excitation_on": sup.action.excitation_on,
            "reason": ev.reason if ev else "",
            "commands": self.commands,
            "gain_estimate": self.law.gain(),
            "gamma": self.law.gamma,
            "reference_limited_count": self.limiter.limited,
            **{f"{k}_count": v for k, v in self.flags.items()},
        }
        st = M.diagnostic_status(self.f, level, self.name, message, values)
        return M.diagnostic_array(self.f, round(t_now * 1e9), [st])


def parse_input(topic: str, msg) -> tuple[float, np.ndarray]:
    """``(header time [s], values)`` of one input message; MessageError when malformed.

    state: ``[phi, theta, u, v, w, p, q, r]`` (FRD); rotor_speeds: Omega (4);
    velocity_reference: ``[u_d, v_d, w_d, r_d]`` (FRD); excitation: u_e (4).
    """
    if topic == "state":
        s = M.state_from_odometry(msg)
        return s.t, np.concatenate([s.euler[:2], s.v_body, s.omega])
    if topic == "rotor_speeds":
        return M.rotor_speeds_from_joint_state(msg)
    if topic == "velocity_reference":
        t, v, r = M.reference_from_twist(msg)
        return t, np.append(v, r)
    if topic == "excitation":
        return M.excitation_from_joint_state(msg)
    raise ConfigError(f"lpv_controller: unknown input topic {topic!r}")


def parse_inputs(topic: str, msgs: list) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised :func:`parse_input` for a whole recording (replay); MessageError names
    the first malformed message."""
    if topic == "state":
        s = M.states_from_odometry(msgs)
        return s.t, np.column_stack([s.euler[:, :2], s.v_body, s.omega])
    if topic == "rotor_speeds":
        return M.channels_from_joint_states(msgs, M.ROTOR_NAMES, field="velocity")
    if topic == "excitation":
        return M.channels_from_joint_states(msgs, M.EXCITATION_NAMES, field="position")
    t = np.empty(len(msgs))
    out = np.empty((len(msgs), 4))
    for i, m in enumerate(msgs):
        t[i], out[i] = parse_input(topic, m)
    return t, out


__all__ = [
    "CommandBuilder",
    "ControllerRuntime",
    "ControllerSettings",
    "INPUT_TOPICS",
    "OUTPUT_TOPICS",
    "load_flight_schedule",
    "parse_input",
    "parse_inputs",
    "settle_gc",
]
