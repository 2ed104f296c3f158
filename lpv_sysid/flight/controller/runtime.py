"""The message-level behaviour of ``lpv_controller_node`` (:class:`ControllerRuntime`): start-up
checks, input parsing and staleness, the law per tick, the safety supervisor and status;
the method is the :mod:`lpv_sysid.flight.controller` docstring."""

from __future__ import annotations

import heapq
from typing import Any, Callable, Optional

import numpy as np

from lpv_sysid.control.law import LpvController, ReferenceLimiter
from lpv_sysid.control.safety import (
    EXTERNAL,
    NON_FINITE,
    OUT_OF_ORDER,
    REFERENCE_ENVELOPE,
    SafetyConfig,
    SafetySupervisor,
)
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.flight.controller.messages import (
    BODY_STATE_NAMES,
    INPUT_TOPICS,
    CommandBuilder,
    parse_input,
    parse_state_cdr,
)
from lpv_sysid.flight.controller.settings import ControllerSettings
from lpv_sysid.flight.controller.startup import RATE_PLANT, design_of, load_flight_schedule
from lpv_sysid.io.messages import (
    LOCKSTEP_ACK,
    MessageError,
    MsgFactory,
    clock_msg,
    diagnostic_array,
    diagnostic_status,
)
from lpv_sysid.models.quadrotor import STATE_NAMES, mixer


#: ``tick_source: state``: samples held for a later state stamp beyond this many are applied
#: at once (oldest first), so a stream stamped far ahead cannot hold the law's inputs back
PENDING_MAX = 256

#: ``lockstep``: answers sent to a matched simulation before :meth:`ControllerRuntime.start`
#: arms (one may be in flight while the match completes; the next arrives after it)
LOCKSTEP_ANSWERS_BEFORE_START = 2


class ControllerRuntime:
    """See module docstring. ``factory`` builds the output messages (MsgFactory)."""

    def __init__(
        self,
        settings: ControllerSettings,
        factory: MsgFactory,
        name: str = "/lpv_sysid/lpv_controller",
        reuse_messages: bool = False,
    ):
        """``reuse_messages`` (the node, which publishes each command before the next tick):
        every tick fills one preallocated ``actuator_command`` message instead of building a
        new one; off (the replay keeps every command) each tick returns a new message."""
        self.settings = settings
        self.f = factory
        self.name = name
        self._log: list[tuple[str, str]] = []
        self.mix = mixer(settings.arm_length)
        self.schedule, info = load_flight_schedule(settings, self.mix)
        self._log += [("info", line) for line in info]
        #: the plant the gains were designed for (startup.design_of): ``virtual_actuator``
        #: (state [body; Mix Omega], inputs ut, ua, ue, ur mixed to ESC commands) or
        #: ``rate_plant`` (state = the body state, inputs thrust + body-rate setpoints; no
        #: rotor_speeds needed, no mixer)
        self.design = design_of(self.schedule, str(settings.gains_file))
        rate = self.design == RATE_PLANT
        self.law = LpvController(
            self.schedule, settings.law_config(), mix=None if rate else self.mix
        )
        #: the input streams the law needs
        self.inputs = tuple(t for t in INPUT_TOPICS if not (rate and t == "rotor_speeds"))
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
                timeouts={k: v for k, v in settings.timeouts.items() if k in self.inputs},
                box_min=tuple(box.min),
                box_max=tuple(box.max),
                box_margin=settings.box_margin,
                stamp_tolerance=settings.stamp_tolerance_s,
                max_body_speed=settings.max_body_speed,
                max_tilt=settings.max_tilt,
                max_body_rate=settings.max_body_rate,
                max_rotor_speed=settings.max_rotor_speed,
                loop_delay_bound=self._loop_delay_bound(settings),
                loop_delay_tolerance=settings.loop_delay_tolerance_s,
            )
        )
        self.body_state: Optional[np.ndarray] = None  # BODY_STATE_NAMES of the state topic (FRD)
        self.omega: Optional[np.ndarray] = None  # rotor speeds (4), rad/s
        # the law's state x = [body_state; Mix Omega] (STATE_NAMES, seed 0 Eq. 7, 14), kept up
        # to date per sample so a tick only reads it; kappa u_e likewise (computed once per
        # excitation message)
        self._law_state = np.empty(len(BODY_STATE_NAMES) if rate else len(STATE_NAMES))
        self._law_body = self._law_state[: len(BODY_STATE_NAMES)]  # view: the state topic
        self._law_delta = self._law_state[len(BODY_STATE_NAMES) :]  # view: Mix Omega
        self._ue_scaled: Optional[np.ndarray] = None
        self._vd_checked: Optional[np.ndarray] = None  # v_d_in the box check last passed
        self._command = CommandBuilder(
            factory, tuple(self.schedule.input_names), reuse=reuse_messages
        )
        self.v_d_in: Optional[np.ndarray] = None  # velocity reference as received (3), FRD
        self.v_d: Optional[np.ndarray] = None  # the reference the law follows (envelope-limited)
        self.u_e: Optional[np.ndarray] = None  # normalised excitation (4)
        self._ref_stamp: Optional[float] = None
        self._t_sample: Optional[float] = None  # last state stamp ticked (tick_source: state)
        self._state_stamp: Optional[float] = None  # stamp of the newest state sample
        self._ref_slope: Optional[np.ndarray] = None  # slope of the limited reference
        #: ``tick_source: state``: input samples received but stamped after the last state
        #: sample ticked, ``(stamp, arrival, topic, values)``; applied in stamp order at the
        #: first state sample stamped at or after them (:meth:`_apply_until`)
        self._pending: list[tuple[float, int, str, np.ndarray]] = []
        self._arrivals = 0
        self._received: set[str] = set()
        #: samples of the law's inputs that arrived stamped at or before a state sample
        #: already ticked (the law of that state did not see them; a replay in the logger's
        #: order may): reported in status
        self.late_inputs = 0
        self.commands = 0
        self.loop_delay_max = 0.0  # the largest loop delay of a tick since start [s]
        self.flags = {"clamped": 0, "saturated": 0, "rate_limited": 0}
        self._abort_reported = False
        #: ``lockstep``: the shell sets this once a simulation subscribes to the answers
        #: (``lockstep_ack`` matched); answers sent since then (:meth:`start` waits for
        #: :data:`LOCKSTEP_ANSWERS_BEFORE_START`)
        self.lockstep_linked = False
        self.answers_linked = 0

    def _loop_delay_bound(self, settings: ControllerSettings) -> float:
        """The loop delay the supervisor holds the commands to [s] (0: none): the gains
        certificate's ``loop_delay.bound_s`` and the ``loop_delay_bound_s`` parameter, the
        smaller of those stated. Refused (ConfigError) when a timer tick would exceed it
        between two healthy state samples."""
        # the format owner (io.formats.certificate.LoopDelay) checked the stated bound
        certified = self.schedule.certificate.loop_delay_bound_s
        stated = [] if certified is None else [float(certified)]
        if settings.loop_delay_bound_s > 0.0:
            stated.append(settings.loop_delay_bound_s)
        if not stated:
            self._log.append(
                (
                    "warn",
                    "no loop-delay bound (certificate.loop_delay.bound_s absent, "
                    "loop_delay_bound_s 0): the loop-delay watchdog is off; only the "
                    "staleness timeouts guard the state's age",
                )
            )
            return 0.0
        bound = min(stated)
        if settings.tick_source == "timer" and bound <= 1.0 / settings.state_rate_hz:
            raise ConfigError(
                f"loop delay bound {1e3 * bound:g} ms is not above one state period "
                f"(1 / state_rate_hz = {1e3 / settings.state_rate_hz:g} ms): with "
                "tick_source timer a healthy state stream would exceed it between samples"
            )
        self._log.append(
            (
                "info",
                f"loop-delay watchdog: abort when commands come from states older than "
                f"{1e3 * bound:g} ms for {1e3 * settings.loop_delay_tolerance_s:g} ms",
            )
        )
        return bound

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
        except MessageError as exc:
            self.on_bad_message(topic, exc, t_now)
            return None
        self.on_sample(topic, t, values, t_now)
        return t

    def on_input(self, topic: str, msg, t_now: float) -> list:
        """:meth:`on_message`, then what to publish: with ``tick_source: state`` a state
        sample newer than the last one ticked runs the law at its stamp (:meth:`tick`)."""
        t = self.on_message(topic, msg, t_now)
        return [] if t is None else self._after_sample(topic, t, t_now)

    def on_state_cdr(self, data: bytes, t_now: float, deserialize: Callable[[bytes], Any]) -> list:
        """:meth:`on_input` of a serialized ``state`` message (the node's raw subscription):
        the 13 values the law needs read from the CDR bytes (:func:`parse_state_cdr`), the
        same sample, checks and commands; a message that needs the validating path goes
        through ``deserialize(data)`` and :meth:`on_input`, which names the problem."""
        try:
            parsed = parse_state_cdr(data)
        except MessageError as exc:
            self.on_bad_message("state", exc, t_now)
            return []
        if parsed is None:
            return self.on_input("state", deserialize(data), t_now)
        t, values = parsed
        self.on_sample("state", t, values, t_now)
        return self._after_sample("state", t, t_now)

    def on_parsed_input(self, topic: str, t: float, values: np.ndarray, t_now: float) -> list:
        """:meth:`on_input` for an input already parsed (:func:`parse_inputs`, the replay)."""
        self.on_sample(topic, t, values, t_now)
        return self._after_sample(topic, t, t_now)

    def _after_sample(self, topic: str, t: float, t_now: float) -> list:
        """``tick_source: state``: a state sample newer than the last one ticked runs the law
        at its stamp; with ``lockstep`` every such sample is answered -- by its command, or,
        when the tick sends none (not started, aborted), by ``lockstep_ack`` stamped with it
        (the lock-stepped simulation integrates past a sample only once it is answered, so
        its time never runs ahead of what this controller has processed, started or not)."""
        if (
            self.settings.tick_source == "state"
            and topic == "state"
            and (self._t_sample is None or t > self._t_sample)
        ):
            self._t_sample = t
            self._apply_until(t, t_now)
            out = self.tick(t_now, t_sample=t)
            if self.settings.lockstep:
                if not any(name == "actuator_command" for name, _ in out):
                    out.append((LOCKSTEP_ACK[0], clock_msg(self.f, round(t * 1e9))))
                if self.lockstep_linked:
                    self.answers_linked += 1
            return out
        return []

    def on_timer(self, t_now: float) -> list:
        """The node's timer (:attr:`ControllerSettings.timer_period_s`): the law step
        (``tick_source: timer``) or only the staleness watch (``state``: a silent state
        stream must still abort)."""
        if self.settings.tick_source == "timer":
            return self.tick(t_now)
        return self.watchdog(t_now)

    def on_bad_message(self, topic: str, exc: Exception, t_now: float) -> None:
        if self.supervisor.armed:
            self.supervisor.abort(t_now, NON_FINITE, f"{topic}: {exc}")
        else:
            self._log.append(("warn", f"{topic} rejected before start: {exc}"))

    def on_sample(self, topic: str, t: float, values: np.ndarray, t_now: float) -> None:
        """Parsed input (see :func:`parse_input`): header time ``t`` [s], ``values``.

        The supervisor judges every sample on arrival (staleness, order, physical limits,
        excitation size). What the law sees: with ``tick_source: timer`` the newest sample
        received; with ``state`` the newest sample of each stream stamped at or before the
        state sample the law steps on (held until then, :meth:`_apply_until`), so each command
        is a function of the recorded samples by their stamps, not of the order in which the
        transport delivered them -- a replay of the bag computes the same command (measured on
        PX4 SITL through the ROS graph, newest-received: 90.6-94.0 % of 5880-5951 commands
        replayed identically)."""
        sup = self.supervisor
        sup.on_input(topic, t, values, t_now)
        self._received.add(topic)
        if topic == "state":
            if sup.armed and not sup.aborted:
                sup.check_state(t_now, values)  # physically absurd -> abort
            self.body_state = values
            self._state_stamp = t
            self._law_body[:] = values
            return
        if topic == "rotor_speeds":
            if sup.armed and not sup.aborted:
                sup.check_rotors(t_now, values)
        elif topic == "excitation":
            if sup.armed and not sup.aborted:
                sup.check_excitation(
                    t_now, self.settings.excitation_gain * values, self.excitation_limit
                )
        if self.settings.tick_source != "state":
            self._apply(topic, t, values, t_now)
            return
        if topic in self.inputs and self._t_sample is not None and t <= self._t_sample:
            self.late_inputs += 1
        self._arrivals += 1
        heapq.heappush(self._pending, (t, self._arrivals, topic, values))
        while len(self._pending) > PENDING_MAX:
            self._apply_until(self._pending[0][0], t_now)

    def _apply_until(self, t_sample: float, t_now: float) -> None:
        """Apply the held samples stamped at or before ``t_sample``, in stamp order."""
        while self._pending and self._pending[0][0] <= t_sample:
            t, _, topic, values = heapq.heappop(self._pending)
            self._apply(topic, t, values, t_now)

    def _apply(self, topic: str, t: float, values: np.ndarray, t_now: float) -> None:
        """A non-state sample becomes the law's input (rotor speeds, reference, excitation)."""
        sup = self.supervisor
        if topic == "rotor_speeds":
            self.omega = values
            if self._law_delta.size:
                self.mix.dot(values, out=self._law_delta)  # delta = Mix Omega (Eq. 7)
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

    def missing_inputs(self) -> list:
        """The input streams of which no sample has arrived yet."""
        return [topic for topic in self.inputs if topic not in self._received]

    def lockstep_ready(self) -> bool:
        """Without ``lockstep`` always; with it once the simulation's subscription to the
        answers matched and :data:`LOCKSTEP_ANSWERS_BEFORE_START` answers went out since: the
        simulation then waits for every state sample this controller has not answered, so
        its sim time cannot run ahead of an armed controller. Measured under real Jazzy
        (load 10-17, the start called at once and again while refused): without this wait
        the start came in the controller's first wake with its inputs, before DDS had
        matched the answers to the simulation; the simulation ran on the wall clock past
        the start and the controller aborted stale (5 of 6 starts)."""
        return not self.settings.lockstep or self.answers_linked >= LOCKSTEP_ANSWERS_BEFORE_START

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
        if wait_for_inputs and not self.lockstep_ready():
            return False, (
                "lockstep: no answer received yet by the simulation (lockstep_ack "
                f"{'matched' if self.lockstep_linked else 'not matched'}): start once it "
                "waits for this controller"
            )
        sup.arm(t_now)
        self.loop_delay_max = 0.0
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
        ``t_now``), which also stamps the command. The loop delay -- ``t_now`` minus the stamp of
        the state the step uses -- is held to the certified bound
        (:meth:`SafetySupervisor.check_loop_delay`)."""
        sup = self.supervisor
        out: list[tuple[str, Any]] = []
        if not sup.armed:
            return out
        t_law = t_now if t_sample is None else float(t_sample)
        sup.check(t_now)
        t_state = self._state_stamp if t_sample is None else t_law
        if t_state is not None:
            if t_now - t_state > self.loop_delay_max:
                self.loop_delay_max = t_now - t_state
            sup.check_loop_delay(t_now, t_state)
        if (
            sup.aborted
            or self._ue_scaled is None
            or self.body_state is None
            or (self.omega is None and "rotor_speeds" in self.inputs)
        ):
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
            u, info = self.law.step(
                t_law, self._law_state, self.reference_at(t_law), self._ue_scaled
            )
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
            elif not self.lockstep_ready():
                message += "; no answer received yet by the lock-stepped simulation"
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
            "loop_delay_max_ms": 1e3 * self.loop_delay_max,
            "late_input_count": self.late_inputs,
            "loop_delay_bound_ms": 1e3 * sup.config.loop_delay_bound,
            **{f"{k}_count": v for k, v in self.flags.items()},
        }
        st = diagnostic_status(self.f, level, self.name, message, values)
        return diagnostic_array(self.f, round(t_now * 1e9), [st])
