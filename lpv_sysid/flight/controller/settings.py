"""The parameters of lpv_controller_node (:class:`ControllerSettings`): the one declaration of
every key of config/lpv_controller.yaml, shared by the node and ``lpv-sysid replay``
(:mod:`lpv_sysid.configuration.parameters`: the rclpy declarations are generated from it, and it
validates every path the same way, cross-field rules included).

Timeouts follow a declared rule (:meth:`ControllerSettings.validate`): every stream's
``timeout >= TIMEOUT_PERIODS / <stream>_rate_hz + input_latency_s`` (the publication rate and
the p99 delivery latency measured on the machine), so a healthy stream never aborts on its
own jitter.
"""

from __future__ import annotations

from dataclasses import dataclass

from lpv_sysid.configuration.parameters import Settings, double, doubles, flag, text
from lpv_sysid.control.law import KAPPA_MAX, KAPPA_MIN, LpvControllerConfig

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
class ControllerSettings(Settings):
    """The node's parameters (config/lpv_controller.yaml): the one declaration."""

    WHERE = "lpv_controller"

    gains_file: str = text(
        "",
        "gains.yaml from `lpv-sysid synthesize` (validated, hash, "
        "closed-loop stability and design envelope checked at start)",
        nonempty=True,
    )
    models_file: str = text("", "vertex_models.yaml the gains must match (optional)")
    signals_file: str = text(
        "",
        "phase-2 signals.npz (or its directory) to be flown: checked at start against the "
        "gains (v_d inside the scheduling box, design envelope, excitation_gain x u_e within "
        "the designed excitation peak); empty: only the run-time checks",
    )
    seal_key_file: str = text(
        "",
        "operator seal key (32 raw bytes or 64 hex characters): the gains file must carry a "
        "keyed seal made with it (seal.hmac_sha256); empty: the unkeyed seal is checked",
    )
    rate_hz: float = double(250.0, "actuator command rate [Hz]", 1.0, 2000.0)
    state_timeout_s: float = double(0.02, "state older than this -> abort [s]", 0.001, 1.0)
    rotor_timeout_s: float = double(0.05, "rotor_speeds older than this -> abort [s]", 0.001, 1.0)
    reference_timeout_s: float = double(
        0.1, "velocity_reference older than this -> abort [s]", 0.001, 1.0
    )
    excitation_timeout_s: float = double(
        0.1, "excitation older than this -> abort [s]", 0.001, 1.0
    )
    stamp_tolerance_s: float = double(
        0.01,
        "header stamps may lead the node clock, or lag it beyond a stream's timeout, "
        "by this much (transport latency) [s]; node clock = sim time under use_sim_time",
        0.0,
        0.5,
    )
    tick_source: str = text(
        "timer",
        "timer: a law step every 1 / rate_hz of the node clock, on the newest samples "
        "received; state: a law step on each state sample, at its stamp (the freshest sample, "
        "no tick phase; the lock-stepped sim_vehicle waits for exactly that command), the "
        "timer then only judges staleness",
        choices=TICK_SOURCES,
    )
    lockstep: bool = flag(
        False,
        "a lock-stepped simulation is the clock (sim.launch.py, sim_vehicle lockstep): answer "
        "every state sample -- with its actuator_command, or on lockstep_ack while not "
        "commanding (before start, after an abort) -- so the simulation never integrates past "
        "a sample the controller has not processed, started or not (needs tick_source state); "
        "false on a vehicle",
    )
    reference_hold: str = text(
        "zoh",
        "the reference between its messages: zoh holds it (a staircase: its steps reach "
        "the feedforward's derivative filter), foh extrapolates the last limited value along "
        "its slope (the played table is piecewise linear; at most reference_timeout_s ahead)",
        choices=REFERENCE_HOLDS,
    )
    state_rate_hz: float = double(
        250.0, "publication rate of state [Hz] (timeout rule)", 1.0, 5000.0
    )
    rotor_rate_hz: float = double(
        100.0, "publication rate of rotor_speeds [Hz] (timeout rule)", 1.0, 5000.0
    )
    reference_rate_hz: float = double(
        100.0, "publication rate of velocity_reference [Hz] (timeout rule)", 1.0, 5000.0
    )
    excitation_rate_hz: float = double(
        100.0, "publication rate of excitation [Hz] (timeout rule)", 1.0, 5000.0
    )
    input_latency_s: float = double(
        0.0,
        "p99 of receipt time minus header stamp of the input streams, measured on the "
        f"target machine (config/lpv_controller.yaml: this machine's) [s]; every timeout >= "
        f"{TIMEOUT_PERIODS} / rate + this",
        0.0,
        1.0,
    )
    box_margin: float = double(
        0.0,
        "tolerance around the scheduling box [m/s] (at most "
        f"{BOX_MARGIN_MAX_FRACTION:g} of its narrowest axis)",
        0.0,
        1.0,
    )
    max_body_speed: float = double(
        30.0, "|body velocity| of a state sample beyond this -> abort [m/s]", 1.0, 100.0
    )
    max_tilt: float = double(1.2, "|roll| or |pitch| beyond this -> abort [rad]", 0.1, 1.5)
    max_body_rate: float = double(20.0, "|p|, |q| or |r| beyond this -> abort [rad/s]", 1.0, 100.0)
    max_rotor_speed: float = double(
        5000.0, "a rotor speed outside [0, this] -> abort [rad/s]", 10.0, 1e5
    )
    excitation_gain: float = double(
        1.0, "excitation multiplier kappa (seed 0 Eq. 33)", KAPPA_MIN, KAPPA_MAX
    )
    arm_length: float = double(0.225, "arm length of the mixer (seed 0 Eq. 7) [m]", 0.01, 10.0)
    u_esc_min: float = double(
        0.0, "lower ESC command limit (< u_esc_max, below every vertex trim)", 0.0, 1.0
    )
    u_esc_max: float = double(
        1.0, "upper ESC command limit (> u_esc_min, above every vertex trim)", 0.0, 1.0
    )
    rate_limit: tuple = doubles(
        (),
        "per-channel rate limit of u [1/s] (unset: none); 0.01 .. 1000 /s: a slower limit "
        "freezes the command (the feedback no longer acts)",
        lo=0.01,
        hi=1000.0,
        lengths=(0, 4),
    )
    monitor_margin: float = double(
        1.2, "bound monitor: abort when gain > gamma x margin", 1.0, 10.0
    )
    monitor_min_energy: float = double(
        0.05,
        "bound monitor: ||u_e||^2 before judging (the design signal has 1 per period, Eq. 26)",
        1e-6,
        1.0,
    )
    monitor_window_s: float = double(
        0.0,
        "> 0: exponentially forgetting monitor window [s] (>= 1 s); 0: running from start",
        0.0,
        1e4,
    )
    feedforward: bool = flag(True, "reference feedforward when gains.yaml has F_ff")
    ff_filter_tau: float = double(
        0.05, "derivative filter of velocity_reference (a) [s]", 0.0, 2.0
    )
    ff_jerk_tau: float = double(0.2, "jerk stage of the derivative filter (F_jerk) [s]", 0.0, 5.0)
    envelope_margin: float = double(
        1.5,
        "abort when the reference rate/acceleration or kappa u_e exceed the gains' design "
        "envelope (certificate.design) by this factor",
        1.0,
        10.0,
    )
    loop_delay_bound_s: float = double(
        0.0,
        "loop delay bound [s] when the gains certificate states none "
        "(certificate.loop_delay.bound_s); with both, the smaller. A command computed from a "
        "state whose stamp is older than this for loop_delay_tolerance_s or longer aborts. "
        "0 and no certified bound: the loop-delay watchdog is off (logged at start)",
        0.0,
        1.0,
    )
    loop_delay_tolerance_s: float = double(
        0.02,
        "how long the loop delay may stay above its bound before the abort [s] (isolated "
        "scheduling hiccups pass; 0: the first command above the bound aborts)",
        0.0,
        1.0,
    )
    auto_start: bool = flag(False, "start commanding without the service")
    status_rate_hz: float = double(2.0, "status publication rate [Hz]", 0.1, 100.0)

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
        if self.lockstep and self.tick_source != "state":
            self.fail(
                "lockstep needs tick_source state (the simulation waits for the answer to "
                f"each state sample), got tick_source {self.tick_source}"
            )
        if 0.0 < self.monitor_window_s < 1.0:
            self.fail(
                f"monitor_window_s must be 0 (running) or >= 1 s, got {self.monitor_window_s:g}"
            )

    def min_timeout(self, name: str) -> float:
        """The least value the timeout rule allows for the timeout parameter ``name``."""
        return TIMEOUT_PERIODS / getattr(self, _RATES[name]) + self.input_latency_s

    @property
    def timer_period_s(self) -> float:
        """The node's timer: ``1 / rate_hz`` with ``tick_source: timer`` (the law step);
        with ``state`` the timer only watches for a silent stream, every
        ``stamp_tolerance_s`` -- a silent stream is then judged stale at most its timeout +
        stamp tolerance after its last sample, the allowance the stamp checks already give
        (0.01 s: 100 timer callbacks a second instead of 250 beside the state ticks)."""
        return 1.0 / self.rate_hz if self.tick_source == "timer" else self.stamp_tolerance_s

    @property
    def loop_delay_s(self) -> float:
        """The configured loop delay [s] (:func:`lpv_sysid.control.safety.loop_delay_s` of
        these settings): what the start-up check holds against the certificate's bound."""
        from lpv_sysid.control.safety import loop_delay_s

        return loop_delay_s(
            self.tick_source, self.rate_hz, self.state_rate_hz, self.input_latency_s
        )

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
