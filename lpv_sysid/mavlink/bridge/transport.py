"""Setpoint transports: how a core command becomes MAVLink for PX4 OFFBOARD.

A transport turns a setpoint object into MAVLink messages; the bridge does not care
which. Implementations here are the ones that can be exercised end to end against the
simulated vehicle (and that PX4 v1.16 accepts over MAVLink):

- :class:`VelocityTransport` (phase 1): SET_POSITION_TARGET_LOCAL_NED, velocity only
  (type_mask 0x0FC7) or velocity + yaw rate (0x07C7), in MAV_FRAME_BODY_NED (PX4 rotates
  the vector by the current *yaw only*) or MAV_FRAME_LOCAL_NED (the bridge rotates the
  body reference by the full attitude R_IB of the latest telemetry, seed 0 Eq. 1).
- :class:`AttitudeRateTransport` (phase 2 fallback): the virtual actuator command
  u = (ut, ua, ue, ur) of seed 0 Eq. (7)-(8) becomes SET_ATTITUDE_TARGET body rates +
  collective thrust (see docs/px4_transport.md for what is lost).
- :class:`RateSetpointTransport` (phase 2 on PX4, "rate plant"): the command *is*
  u = (thrust, p_sp, q_sp, r_sp) (:data:`RATE_INPUT_NAMES`, normalised thrust and FRD body
  rates in rad/s) and goes out unchanged as SET_ATTITUDE_TARGET; PX4's rate loop is part of
  the identified plant (lpv_sysid/models/rate_plant.py, docs/px4_chain.md), so nothing is
  inverted and the certificate is about exactly what is sent.
  :func:`rate_setpoint_from_attitude_target` reads the same four values back from PX4's
  ATTITUDE_TARGET stream (the setpoints PX4's own velocity/attitude cascade produced).

Direct motor commands (px4_msgs ActuatorMotors over uXRCE-DDS) are not a MAVLink path
and not a dependency of this package; SET_ACTUATOR_CONTROL_TARGET is ignored by PX4 since
about v1.14. docs/px4_transport.md lists what each firmware path supports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from lpv_sysid.errors import ConfigError, SafetyError

MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_NED = 8
TYPE_MASK_VELOCITY = 0x0FC7  # ignore position, acceleration, force, yaw, yaw rate
TYPE_MASK_VELOCITY_YAW_RATE = 0x07C7  # as above but yaw rate used
ATTITUDE_TARGET_IGNORE_ATTITUDE = 128  # ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
_SQ2 = math.sqrt(2.0) / 2.0


@dataclass(frozen=True)
class VelocitySetpoint:
    """Body velocity reference (u_d, v_d, w_d) FRD [m/s] and yaw-rate reference r_d [rad/s]."""

    v_frd: tuple[float, float, float]
    yaw_rate: float = 0.0


@dataclass(frozen=True)
class ActuatorSetpoint:
    """Virtual actuator command u = (ut, ua, ue, ur) of seed 0 Eq. (7) (INPUT_NAMES)."""

    u: tuple[float, float, float, float]


@dataclass(frozen=True)
class TransportContext:
    """What a transport may need besides the setpoint."""

    time_boot_ms: int
    target_system: int
    target_component: int
    q_wxyz: np.ndarray | None = None  # latest attitude (FRD -> NED)
    omega: np.ndarray | None = None  # latest body rates FRD


class SetpointTransport(Protocol):
    name: str

    def encode(self, codec: Any, setpoint: Any, ctx: TransportContext) -> list[Any]:
        """MAVLink messages for ``setpoint`` (raises SafetyError if it cannot be encoded)."""

    def neutral(self) -> Any | None:
        """Setpoint streamed while no fresh command exists (None: stream nothing)."""


#: default of ``BridgeConfig.command_abort_factor``: a command beyond this multiple of the
#: transport's range (thrust, rate) is absurd (a broken law, a corrupt gains file, a
#: hostile publisher) and aborts instead of being clipped to full thrust / full rate
ABSURD_FACTOR = 10.0


def _absurd(what: str, value: float, limit: float, factor: float) -> None:
    """Raise SafetyError (the bridge aborts: hand-back) for ``|value| > factor * limit``;
    commands up to that bound are the law's saturation and are clipped."""
    if abs(value) > factor * limit:
        raise SafetyError(
            f"{what} {value:.6g} is absurd: beyond {factor:g} x the range {limit:g} "
            "(command_abort_factor); aborting, not clipping"
        )


def _finite(name: str, values: Any, n: int) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if a.shape != (n,):
        raise SafetyError(f"{name}: expected {n} values, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise SafetyError(f"{name}: contains NaN or inf")
    return a


class VelocityTransport:
    """Phase-1 velocity setpoints (module docstring)."""

    name = "velocity"

    def __init__(self, frame: str = "body_ned", use_yaw_rate: bool = True) -> None:
        if frame not in ("body_ned", "local_ned"):
            raise ConfigError(f"velocity frame must be 'body_ned' or 'local_ned', got {frame!r}")
        self.frame = frame
        self.use_yaw_rate = bool(use_yaw_rate)
        self.type_mask = TYPE_MASK_VELOCITY_YAW_RATE if use_yaw_rate else TYPE_MASK_VELOCITY

    def neutral(self) -> VelocitySetpoint:
        """Zero velocity: PX4 brakes and hovers (used only during pre-stream)."""
        return VelocitySetpoint((0.0, 0.0, 0.0), 0.0)

    def encode(self, codec: Any, sp: VelocitySetpoint, ctx: TransportContext) -> list[Any]:
        v = _finite("velocity setpoint", sp.v_frd, 3)
        r = float(sp.yaw_rate)
        if not math.isfinite(r):
            raise SafetyError("yaw-rate setpoint is not finite")
        if self.frame == "local_ned":
            if ctx.q_wxyz is None:
                raise SafetyError(
                    "local_ned velocity setpoint needs the vehicle attitude (no telemetry)"
                )
            from lpv_sysid.mavlink.telemetry import quat_to_dcm

            v = quat_to_dcm(ctx.q_wxyz) @ v
            frame = MAV_FRAME_LOCAL_NED
        else:
            frame = MAV_FRAME_BODY_NED
        return [
            codec.set_position_target_local_ned_encode(
                ctx.time_boot_ms,
                ctx.target_system,
                ctx.target_component,
                frame,
                self.type_mask,
                0.0,
                0.0,
                0.0,
                float(v[0]),
                float(v[1]),
                float(v[2]),
                0.0,
                0.0,
                0.0,
                0.0,
                r if self.use_yaw_rate else 0.0,
            )
        ]


class AttitudeRateTransport:
    """Phase-2 fallback: virtual actuator command -> body-rate + thrust setpoint.

    Seed 0 Eq. (7) with PX4 quad-X numbering gives the per-motor normalised commands
    u_ESC = Mix^-1 u. PX4's normalised allocation for a quad-X with unit effectiveness
    (motor_i = T + a_i tau_roll + b_i tau_pitch + c_i tau_yaw, |a_i| = |b_i| = |c_i| = 1)
    inverts that exactly to::

        T = ut,  tau_roll = ua / (4 s),  tau_pitch = ue / (4 s),  tau_yaw = ur / 4,
        s = arm_length * sqrt(2) / 2

    PX4's rate controller produces tau = K_p (omega_sp - omega) (+ I, D, FF terms), so
    the rate setpoint that makes its proportional term reproduce tau is::

        omega_sp = omega_measured + tau / K_p,   K_p = (MC_ROLLRATE_P, MC_PITCHRATE_P,
        MC_YAWRATE_P)

    Lost on this path: the rate integrator/derivative of PX4 act on top (set MC_*RATE_I
    to 0 for identification flights), per-axis effectiveness scaling of PX4's control
    allocator (CA_ROTOR geometry) and THR_MDL_FAC reshape the command, motor saturation
    is handled by PX4's allocator, and one extra sample of latency is added.
    """

    name = "attitude_rate"

    def __init__(
        self,
        arm_length: float,
        rate_p: tuple[float, float, float] = (0.15, 0.15, 0.2),
        max_rate: float = 4.0,
        absurd_factor: float = ABSURD_FACTOR,
    ) -> None:
        if not (arm_length > 0 and math.isfinite(arm_length)):
            raise ConfigError(f"attitude_rate.arm_length must be positive, got {arm_length!r}")
        kp = np.asarray(rate_p, dtype=float)
        if kp.shape != (3,) or not np.isfinite(kp).all() or (kp <= 0).any():
            raise ConfigError(f"attitude_rate.rate_p must be 3 positive numbers, got {rate_p!r}")
        self.s = arm_length * _SQ2
        self.rate_p = kp
        self.max_rate = float(max_rate)
        self.absurd_factor = _factor(absurd_factor)

    def neutral(self) -> None:
        return None  # no safe neutral without a model of the hover thrust: stream nothing

    def thrust_torque(self, u: Any) -> tuple[float, np.ndarray]:
        ut, ua, ue, ur = _finite("actuator command", u, 4)
        return float(ut), np.array([ua / (4 * self.s), ue / (4 * self.s), ur / 4.0])

    def encode(self, codec: Any, sp: ActuatorSetpoint, ctx: TransportContext) -> list[Any]:
        if ctx.omega is None:
            raise SafetyError("attitude_rate transport needs the body rates (no telemetry)")
        thrust, tau = self.thrust_torque(sp.u)
        f = self.absurd_factor
        _absurd("thrust command", thrust, 1.0, f)
        d_omega = tau / self.rate_p
        for axis, d in zip(("roll", "pitch", "yaw"), d_omega):
            _absurd(f"{axis} moment (as a rate increment, rad/s)", float(d), self.max_rate, f)
        omega_sp = np.clip(
            np.asarray(ctx.omega, dtype=float) + d_omega, -self.max_rate, self.max_rate
        )
        thrust = min(max(thrust, 0.0), 1.0)
        return [
            codec.set_attitude_target_encode(
                ctx.time_boot_ms,
                ctx.target_system,
                ctx.target_component,
                ATTITUDE_TARGET_IGNORE_ATTITUDE,
                [1.0, 0.0, 0.0, 0.0],
                float(omega_sp[0]),
                float(omega_sp[1]),
                float(omega_sp[2]),
                thrust,
            )
        ]


#: inputs of the rate plant, in the order of SET_ATTITUDE_TARGET's fields (thrust last there)
RATE_INPUT_NAMES = ("thrust", "p_sp", "q_sp", "r_sp")
RATE_INPUT_UNITS = ("1", "rad/s", "rad/s", "rad/s")


class RateSetpointTransport:
    """Phase 2 with PX4's rate loop inside the plant: ``ActuatorSetpoint.u`` is
    (thrust, p_sp, q_sp, r_sp), sent as SET_ATTITUDE_TARGET (attitude ignored).

    The command is clipped to PX4's ranges only (thrust [0, 1], |rate| <= ``max_rate``);
    there is no inversion and no telemetry feedback inside the transport (unlike
    :class:`AttitudeRateTransport`, whose omega_sp = omega + tau / K_p feeds the telemetry's
    rate noise straight back into PX4's rate loop). It takes BridgeCore's ``attitude_rate``
    command path (``on_actuator_command`` with 4 values); ``input_form`` tells the two apart.
    """

    name = "attitude_rate"
    input_form = "rate_setpoint"

    def __init__(
        self,
        max_rate: float = 2.0,
        thrust_min: float = 0.05,
        thrust_max: float = 0.95,
        absurd_factor: float = ABSURD_FACTOR,
    ) -> None:
        if not (math.isfinite(max_rate) and max_rate > 0):
            raise ConfigError(f"rate_setpoint.max_rate must be positive, got {max_rate!r}")
        if not (0.0 <= thrust_min < thrust_max <= 1.0):
            raise ConfigError(
                f"rate_setpoint thrust range must satisfy 0 <= min < max <= 1, got "
                f"[{thrust_min!r}, {thrust_max!r}]"
            )
        self.max_rate = float(max_rate)
        self.thrust_min = float(thrust_min)
        self.thrust_max = float(thrust_max)
        self.absurd_factor = _factor(absurd_factor)

    def neutral(self) -> None:
        return None  # the hover thrust is vehicle-specific: stream only what the law commands

    def clip(self, u: Any) -> np.ndarray:
        """The command PX4 receives: thrust in [thrust_min, thrust_max], rates in +-max_rate;
        SafetyError (abort) beyond ``absurd_factor`` times those ranges."""
        a = _finite("rate setpoint", u, 4).copy()
        f = self.absurd_factor
        _absurd("thrust setpoint", float(a[0]), self.thrust_max, f)
        for name, r in zip(RATE_INPUT_NAMES[1:], a[1:]):
            _absurd(name, float(r), self.max_rate, f)
        a[0] = min(max(a[0], self.thrust_min), self.thrust_max)
        a[1:] = np.clip(a[1:], -self.max_rate, self.max_rate)
        return a

    def encode(self, codec: Any, sp: ActuatorSetpoint, ctx: TransportContext) -> list[Any]:
        a = self.clip(sp.u)
        return [
            codec.set_attitude_target_encode(
                ctx.time_boot_ms,
                ctx.target_system,
                ctx.target_component,
                ATTITUDE_TARGET_IGNORE_ATTITUDE,
                [1.0, 0.0, 0.0, 0.0],
                float(a[1]),
                float(a[2]),
                float(a[3]),
                float(a[0]),
            )
        ]


def _factor(f: float) -> float:
    if not (math.isfinite(f) and 1.0 <= f <= 100.0):
        raise ConfigError(f"command_abort_factor must be in [1, 100], got {f!r}")
    return float(f)


def rate_setpoint_from_attitude_target(msg: Any) -> tuple[float, np.ndarray] | None:
    """(time_boot_ms / 1000, [thrust, p_sp, q_sp, r_sp]) of a PX4 ATTITUDE_TARGET, or None
    when a field is not finite. PX4 fills body_*_rate from vehicle_rates_setpoint and thrust
    from the attitude setpoint's -thrust_body[2] (normalised, as SET_ATTITUDE_TARGET takes it)."""
    vals = np.array(
        [msg.thrust, msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate], dtype=float
    )
    if not np.isfinite(vals).all():
        return None
    return float(msg.time_boot_ms) * 1e-3, vals


#: :class:`AttitudeTargetEcho`: an ATTITUDE_TARGET whose time_boot_ms moved by at most this
#: [ms] since the previous one repeats PX4's last attitude setpoint
STALE_MS = 1


class AttitudeTargetEcho:
    """PX4's ATTITUDE_TARGET read as the setpoints PX4 executes: ``[thrust, p_sp, q_sp, r_sp]``.

    PX4 (``src/modules/mavlink/streams/ATTITUDE_TARGET.hpp``, v1.14-1.16) fills the body rates
    from ``vehicle_rates_setpoint`` but ``thrust`` and ``time_boot_ms`` from
    ``vehicle_attitude_setpoint``; when no attitude setpoint has been published for 500 ms --
    OFFBOARD body-rate control (SET_ATTITUDE_TARGET with the attitude ignored), where PX4 puts
    the thrust sent straight into ``vehicle_rates_setpoint`` -- it keeps sending the last
    attitude setpoint's thrust and ``time_boot_ms`` beside fresh rates. So a ``time_boot_ms``
    that did not advance marks a stale thrust: it is replaced by the thrust of the last
    rate-only SET_ATTITUDE_TARGET sent (:meth:`on_sent`), which is the thrust PX4 executes;
    with none sent, the sample is dropped (``None``). Measured on PX4 v1.16 SITL, phase 2
    through the ROS graph: the echoed thrust had std 0.0022 around the hover value 0.495
    while the thrust commanded had std 0.038 (the heave row could not be identified from it).
    """

    def __init__(self) -> None:
        self._last_boot_ms: int | None = None
        #: thrust of the last rate-only SET_ATTITUDE_TARGET sent (None: none yet)
        self.sent_thrust: float | None = None
        #: echoes whose thrust was stale: replaced by the sent thrust / dropped (none sent)
        self.replaced = 0
        self.dropped = 0

    def on_sent(self, msg: Any) -> None:
        """A message sent to PX4: a rate-only SET_ATTITUDE_TARGET sets :attr:`sent_thrust`."""
        kind = getattr(msg, "get_type", None)  # MAVROS-bound setpoints: only RateTarget has it
        if (
            kind is not None
            and kind() == "SET_ATTITUDE_TARGET"
            and int(msg.type_mask) & ATTITUDE_TARGET_IGNORE_ATTITUDE
        ):
            thrust = float(msg.thrust)
            if math.isfinite(thrust):
                self.sent_thrust = thrust

    def on_target(self, msg: Any) -> np.ndarray | None:
        """``[thrust, p_sp, q_sp, r_sp]`` of an ATTITUDE_TARGET, thrust as PX4 executes it
        (class docstring); None when a field is not finite or the thrust is unknown."""
        got = rate_setpoint_from_attitude_target(msg)
        boot_ms = int(msg.time_boot_ms)
        # within STALE_MS: MAVROS restamps time_boot_ms through its time sync (a frozen one
        # moves by the sync's corrections), a fresh attitude setpoint is >= 1 stream period on
        stale = self._last_boot_ms is not None and abs(boot_ms - self._last_boot_ms) <= STALE_MS
        self._last_boot_ms = boot_ms
        if got is None:
            return None
        values = got[1]
        if stale:
            if self.sent_thrust is None:
                self.dropped += 1
                return None
            values[0] = self.sent_thrust
            self.replaced += 1
        return values


def make_transport(kind: str, **kw: Any) -> SetpointTransport:
    if kind == "velocity":
        return VelocityTransport(**kw)
    if kind == "attitude_rate":
        return AttitudeRateTransport(**kw)
    if kind == "rate_setpoint":
        return RateSetpointTransport(**kw)
    raise ConfigError(
        f"command transport {kind!r} unknown; use 'velocity', 'attitude_rate' or 'rate_setpoint' "
        "(direct motor control needs uXRCE-DDS, see docs/px4_transport.md)"
    )
