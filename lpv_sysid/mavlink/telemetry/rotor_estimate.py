"""Rotor speeds from the motor outputs when the vehicle sends no ESC telemetry.

SIH and vehicles with plain PWM ESCs publish no ESC_STATUS, but PX4 streams what it writes
to the motors: ACTUATOR_OUTPUT_STATUS (id 375: ``time_usec``, ``active``, ``actuator[32]``
float) and SERVO_OUTPUT_RAW (id 36: ``time_usec`` uint32, ``port``, ``servo1_raw`` ..
``servo16_raw`` uint16), both copies of the uORB topic ``actuator_outputs`` (PX4 v1.16
``src/modules/mavlink/streams``). The rotor speeds follow from the first-order motor model
of seed 0 Eq. (8),

    dOmega_i/dt = -a_Omega Omega_i + b_Omega u_ESC,i,   Omega_i held in [omega_min, omega_max],

with a_Omega, b_Omega and the limits of the airframe (``models/quadrotor.QuadrotorParams``,
``config/quadrotor.yaml``; values identified later can be set here).

Output -> u_ESC (``mapping``; ``output_min`` / ``output_max`` override the range):

==============  ==================  =====================================================
mapping         output range        vehicles
==============  ==================  =====================================================
``pwm``         1000 .. 2000 us     PX4 PWM outputs (PWM_MAIN_MINx/MAXx defaults) and SITL
                                    (pwm_out_sim writes 900 disarmed, 1000 .. 2000)
``dshot``       1 .. 1999           PX4 DShot driver (0 = disarmed)
``normalized``  0 .. 1              outputs already normalised to [0, 1]
``symmetric``   -1 .. 1             outputs normalised to [-1, 1]
==============  ==================  =====================================================

``u_ESC = clip((x - output_min) / (output_max - output_min), 0, 1)``. A value below
``output_min`` (the disarmed value, e.g. PWM 900 or DShot 0) or NaN means the motor is
stopped: Omega = 0 (below the model's idle speed, which applies only to a running motor).

Integration is exact for a zero-order hold of each output sample (PX4 writes the output
and holds it until the next one): between vehicle times t_k and t_{k+1}

    Omega(t_{k+1}) = Omega_ss + (Omega(t_k) - Omega_ss) exp(-a_Omega (t_{k+1} - t_k)),
    Omega_ss = b_Omega u_ESC(t_k) / a_Omega,

clipped to [omega_min, omega_max] (the clip of the monotone unconstrained solution is the
solution with the speed held at the limit).

``hold: linear`` (first-order hold) is for a stream that samples a faster output: MAVLink's
ACTUATOR_OUTPUT_STATUS at 50 Hz of PX4's outputs written at the control rate (250 Hz in
SITL, up to 1-2 kHz on hardware). Holding each 50 Hz sample until the next one delays the
estimate by half a sample period on average (10 ms at 50 Hz, 2 ms at 250 Hz); taking the
output as a ramp from u_ESC(t_k) to u_ESC(t_{k+1}) (known when the sample at t_{k+1}
arrives, so still causal) removes that delay:

    Omega(t_{k+1}) = ss_{k+1} + (Omega(t_k) - ss_k) e - (ss_{k+1} - ss_k) (1 - e) / (a_Omega dt),
    ss_j = b_Omega u_ESC(t_j) / a_Omega,  e = exp(-a_Omega dt),

the exact solution for the ramp. Measured on PX4 SITL v1.16 (SIH, 2026-12-02, 3 vertices):
with ``zero`` the roll/pitch damping identified from the bags' 50 Hz estimate is
A[p,p] -3.7 .. -4.3, A[q,q] -4.3 .. -4.5 (1/s), from the ULog's 250 Hz outputs -3.1 .. -3.3;
the ULog's outputs cut to 50 Hz give the bags' values (-3.8 .. -4.4), so the difference is
the hold, not the recording; with ``linear`` 50 Hz and 250 Hz agree (-2.7 .. -3.1).

The first sample, a gap longer than ``max_gap`` or a time that does not advance restarts at
the steady state of the newest output (after a gap the history is unknown; the steady state
is the best guess and is reached within 5 / a_Omega = 0.4 s for the default airframe).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping, Sequence

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.configuration.fields import is_finite_number
from lpv_sysid.errors import ConfigError
from lpv_sysid.io.messages import ROTOR_SOURCES
from lpv_sysid.mavlink import px4

#: output range (output_min, output_max) of each mapping name
MAPPINGS: dict[str, tuple[float, float]] = {
    "pwm": (px4.PWM_MIN_US, px4.PWM_MAX_US),
    "dshot": (1.0, 1999.0),
    "normalized": (0.0, 1.0),
    "symmetric": (-1.0, 1.0),
}
#: message sources of the motor outputs; ``auto``: ACTUATOR_OUTPUT_STATUS, SERVO_OUTPUT_RAW
#: only while ACTUATOR_OUTPUT_STATUS is not streamed
SOURCES = ("auto", "actuator_output_status", "servo_output_raw")
#: motor output between two samples (module docstring)
HOLDS = ("zero", "linear")
ESC, ESTIMATED = ROTOR_SOURCES  # RotorSample.source values (rotor_speeds frame_id)
#: streams the estimate needs [Hz]; PX4 sends ACTUATOR_OUTPUT_STATUS only when requested
#: (SITL onboard link: SERVO_OUTPUT_RAW 10 Hz by default); 50 Hz keeps rotor_speeds within
#: the controller runtime's 0.05 s staleness limit
MOTOR_OUTPUT_STREAMS: tuple[tuple[str, float], ...] = (
    ("ACTUATOR_OUTPUT_STATUS", 50.0),
    ("SERVO_OUTPUT_RAW", 10.0),
)


@dataclass(frozen=True)
class MotorModel:
    """Seed 0 Eq. (8) for one motor: a_Omega [1/s], b_Omega [rad/s^2], limits [rad/s]."""

    a_omega: float
    b_omega: float
    omega_min: float
    omega_max: float

    def __post_init__(self) -> None:
        for name in ("a_omega", "b_omega", "omega_max"):
            v = getattr(self, name)
            if not (is_finite_number(v) and v > 0):
                raise ConfigError(
                    f"rotor_estimate.{name} must be a positive finite number, got {v!r}"
                )
        if not (is_finite_number(self.omega_min) and 0 <= self.omega_min < self.omega_max):
            raise ConfigError(
                f"rotor_estimate.omega_min must be in [0, omega_max = {self.omega_max}), "
                f"got {self.omega_min!r}"
            )

    @classmethod
    def from_params(cls, params: Any) -> "MotorModel":
        """From a :class:`lpv_sysid.models.quadrotor.QuadrotorParams`."""
        return cls(
            float(params.a_omega),
            float(params.b_omega),
            float(params.omega_min),
            float(params.omega_max),
        )

    def steady(self, u_esc: np.ndarray) -> np.ndarray:
        """Steady-state speed b_Omega u / a_Omega, held in the limits."""
        return np.clip(
            self.b_omega / self.a_omega * np.asarray(u_esc, dtype=float),
            self.omega_min,
            self.omega_max,
        )

    def propagate_ramp(
        self, omega: np.ndarray, u0: np.ndarray, u1: np.ndarray, dt: float
    ) -> np.ndarray:
        """Exact solution after ``dt`` s with the input a ramp from ``u0`` to ``u1``
        (first-order hold, module docstring), in the limits."""
        k = self.b_omega / self.a_omega
        ss0, ss1 = k * np.asarray(u0, dtype=float), k * np.asarray(u1, dtype=float)
        e = math.exp(-self.a_omega * dt)
        w = (
            ss1
            + (np.asarray(omega, dtype=float) - ss0) * e
            - (ss1 - ss0) * (1.0 - e) / (self.a_omega * dt)
        )
        return np.clip(w, self.omega_min, self.omega_max)

    def propagate(self, omega: np.ndarray, u_esc: np.ndarray, dt: float) -> np.ndarray:
        """Exact solution after ``dt`` s with ``u_esc`` held (zero-order hold), in the limits."""
        ss = self.b_omega / self.a_omega * np.asarray(u_esc, dtype=float)
        return np.clip(
            ss + (np.asarray(omega, dtype=float) - ss) * math.exp(-self.a_omega * dt),
            self.omega_min,
            self.omega_max,
        )


_OVERRIDE = {"optional": True, "lo": 0.0, "lo_open": True}


@dataclass(frozen=True)
class RotorEstimateConfig:
    """``rotor_estimate`` section of ``config/mavlink_bridge.yaml``, checked by
    :meth:`validate`.

    ``motor_outputs``: 1-based output channel of rotor 1..n (PX4 numbering of DESIGN.md;
    PX4's quad-X default maps Motor 1..4 to outputs 1..4). ``servo_port``: SERVO_OUTPUT_RAW
    ``port`` carrying the motors. ``airframe``: YAML file with a ``quadrotor`` section
    (relative paths: working directory, then the shipped ``config/``); empty: the built-in
    airframe (``QuadrotorParams()`` = ``config/quadrotor.yaml``). ``a_omega`` ..
    ``omega_max``: override the airframe's values (e.g. identified ones), seed 0 Eq. (8).
    """

    enabled: bool = cf.flag(True, "estimate rotor speeds while no fresh ESC telemetry")
    source: str = cf.choice("auto", SOURCES, "message of the motor outputs")
    mapping: str = cf.choice("pwm", tuple(MAPPINGS), "motor output -> u_ESC (module docstring)")
    output_min: float | None = cf.number(
        None, "override of the mapping's output range (low end)", optional=True
    )
    output_max: float | None = cf.number(
        None, "override of the mapping's output range (high end)", optional=True
    )
    motor_outputs: tuple[int, ...] = cf.counts(
        (1, 2, 3, 4), "output channel (1-based) of rotor 1..n", lo=1, hi=32, unique=True
    )
    servo_port: int = cf.count(0, "SERVO_OUTPUT_RAW port of the motors (uint8)", hi=255)
    airframe: str = cf.text(
        "",
        "YAML with a quadrotor section; empty or null: the built-in airframe",
        nonempty=False,
        nullable=True,
    )
    a_omega: float | None = cf.number(None, "a_Omega [1/s] (null: the airframe's)", **_OVERRIDE)
    b_omega: float | None = cf.number(
        None, "b_Omega [rad/s^2 per unit u_ESC] (null: the airframe's)", **_OVERRIDE
    )
    omega_min: float | None = cf.number(
        None,
        "idle speed of a running motor [rad/s] (null: the airframe's)",
        optional=True,
        lo=0.0,
    )
    omega_max: float | None = cf.number(
        None, "largest rotor speed [rad/s] (null: the airframe's)", **_OVERRIDE
    )
    max_gap: float = cf.number(
        0.25,
        "longer gaps between output samples restart the estimate at the steady state [s]; "
        "at most 2 s: across a longer gap the held output says nothing about the motor "
        "(5 / a_Omega = 0.4 s settles it)",
        lo=0.0,
        lo_open=True,
        hi=2.0,
        unit=" s",
    )
    hold: str = cf.choice(
        "zero",
        HOLDS,
        "motor output between samples: zero (held until the next sample: every output PX4 "
        "wrote, e.g. a ULog) or linear (ramp to the next sample: a stream slower than PX4's "
        "control rate, e.g. ACTUATOR_OUTPUT_STATUS at 50 Hz; module docstring)",
    )
    esc_timeout: float = cf.number(
        0.2,
        "ESC telemetry older than this is stale and the estimate is published instead [s]; "
        "at most 1 s: an older rotor speed is no feedback (the controller accepts 0.05 s)",
        lo=0.0,
        lo_open=True,
        hi=1.0,
        unit=" s",
    )

    @classmethod
    def from_dict(
        cls, d: Mapping[str, Any], where: str = "rotor_estimate"
    ) -> "RotorEstimateConfig":
        cfg = cls(**cf.parse_fields(cls, d, where))
        cfg.validate(where)
        return cfg

    def validate(self, where: str = "rotor_estimate") -> None:
        """The declared fields, then: the output range is increasing, SERVO_OUTPUT_RAW
        carries outputs 1..16 only."""
        cf.check_fields(self, where)
        lo, hi = self.output_range()
        if not lo < hi:
            raise cf.error(where, "output_min", f"{lo:g} must be below output_max ({hi:g})")
        if self.source == "servo_output_raw" and max(self.motor_outputs) > 16:
            raise cf.error(
                where,
                "motor_outputs",
                f"SERVO_OUTPUT_RAW carries outputs 1..16, got {list(self.motor_outputs)}",
            )

    def output_range(self) -> tuple[float, float]:
        """(output_min, output_max): the mapping's range unless overridden."""
        lo, hi = MAPPINGS.get(self.mapping, (math.nan, math.nan))
        return (
            float(self.output_min) if self.output_min is not None else lo,
            float(self.output_max) if self.output_max is not None else hi,
        )

    def motor_model(self) -> MotorModel:
        """Eq. (8) parameters: the airframe's, with this section's overrides."""
        base = MotorModel.from_params(load_airframe(self.airframe))
        over = {
            f.name: float(getattr(self, f.name))
            for f in fields(MotorModel)
            if getattr(self, f.name) is not None
        }
        return MotorModel(**{**base.__dict__, **over})


def with_motor_output_streams(link: Any, cfg: RotorEstimateConfig) -> Any:
    """``link`` (a :class:`~lpv_sysid.mavlink.link.LinkConfig`) with
    :data:`MOTOR_OUTPUT_STREAMS` added when the estimate is enabled and the streams are not
    configured (a configured rate, also 0 = off, is kept)."""
    import dataclasses

    if not cfg.enabled:
        return link
    have = {name for name, _ in link.streams}
    extra = tuple((n, r) for n, r in MOTOR_OUTPUT_STREAMS if n not in have)
    return dataclasses.replace(link, streams=tuple(link.streams) + extra) if extra else link


def load_airframe(path: str) -> Any:
    """QuadrotorParams of the ``quadrotor`` section of ``path`` ('' = built-in defaults)."""
    from lpv_sysid.models.quadrotor import QuadrotorParams

    if not path:
        return QuadrotorParams()
    from pathlib import Path

    from lpv_sysid.io.files import read_yaml

    p = Path(path)
    if not p.is_absolute() and not p.is_file():
        try:
            from lpv_sysid.configuration.defaults import config_dir

            shipped = config_dir() / p
        except ConfigError:
            shipped = p
        p = shipped if shipped.is_file() else p
    if not p.is_file():
        raise ConfigError(
            f"rotor_estimate.airframe: {path}: no such file (looked in the working "
            "directory and the shipped config/)"
        )
    d = read_yaml(p, f"rotor_estimate.airframe {p}")
    if not isinstance(d, Mapping) or not isinstance(d.get("quadrotor"), Mapping):
        raise ConfigError(f"rotor_estimate.airframe {p}: no 'quadrotor' section")
    try:
        return QuadrotorParams.from_dict(d["quadrotor"])
    except ConfigError as exc:
        raise ConfigError(f"rotor_estimate.airframe {p}: {exc}") from None


@dataclass
class EstimatorStats:
    samples: int = 0
    restarts: int = 0  # first sample, gaps > max_gap, time not advancing


class RotorSpeedEstimator:
    """Omega (rad/s, one per motor) from motor output samples; see the module docstring."""

    def __init__(
        self,
        model: MotorModel,
        output_range: tuple[float, float],
        max_gap: float = 0.25,
        hold: str = "zero",
    ) -> None:
        if hold not in HOLDS:
            raise ConfigError(f"rotor_estimate: hold {hold!r} is not one of {HOLDS}")
        self.hold = hold
        lo, hi = float(output_range[0]), float(output_range[1])
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ConfigError(f"rotor_estimate: invalid output range {output_range!r}")
        self.model = model
        self.lo, self.hi = lo, hi
        self.max_gap = float(max_gap)
        self.stats = EstimatorStats()
        self._t: float | None = None
        self._u: np.ndarray | None = None
        self._stopped: np.ndarray | None = None
        self._omega: np.ndarray | None = None

    @classmethod
    def from_config(cls, cfg: RotorEstimateConfig) -> "RotorSpeedEstimator":
        return cls(cfg.motor_model(), cfg.output_range(), cfg.max_gap, cfg.hold)

    def u_esc(self, outputs: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """``(u_ESC in [0, 1], stopped)`` of raw output values (stopped: NaN or < output_min)."""
        x = np.asarray(outputs, dtype=float)
        with np.errstate(invalid="ignore"):
            stopped = ~np.isfinite(x) | (x < self.lo)
            u = np.clip((x - self.lo) / (self.hi - self.lo), 0.0, 1.0)
        u[stopped] = 0.0
        return u, stopped

    def reset(self) -> None:
        self._t = self._u = self._stopped = self._omega = None

    @property
    def omega(self) -> np.ndarray | None:
        """The newest estimate (None before the first sample)."""
        return None if self._omega is None else self._omega.copy()

    def update(self, t_vehicle: float, outputs: Sequence[float]) -> np.ndarray:
        """Omega at ``t_vehicle`` [s] given the output held since the previous sample;
        ``outputs`` then becomes the held output."""
        u, stopped = self.u_esc(outputs)
        dt = None if self._t is None else t_vehicle - self._t
        if (
            dt is None
            or not (0.0 < dt <= self.max_gap)
            or self._u is None
            or self._u.shape != u.shape
            or self._omega is None
        ):
            omega = self.model.steady(u)
            omega[stopped] = 0.0
            self.stats.restarts += 1
        elif self.hold == "linear":
            # a motor stopped by this sample: its output held until now, as with ``zero``
            omega = self.model.propagate_ramp(
                self._omega, self._u, np.where(stopped, self._u, u), dt
            )
            omega[self._stopped] = 0.0
        else:
            omega = self.model.propagate(self._omega, self._u, dt)
            omega[self._stopped] = 0.0  # stopped over the interval: not turning
        self._t, self._u, self._stopped, self._omega = float(t_vehicle), u, stopped, omega
        self.stats.samples += 1
        return omega.copy()
