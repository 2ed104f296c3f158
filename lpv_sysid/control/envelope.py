"""Safety envelope of an offboard flight (pure: no I/O, no clock; every call carries its time).

Enforced by the bridge core (:class:`lpv_sysid.mavlink.bridge.BridgeCore`) on every state
sample and every setpoint while it streams setpoints, so it holds with or without ROS and
whatever node produces the commands. Limits (``config/mavlink_bridge.yaml`` section
``envelope``; heights are *above home*, positive up; NED inside):

- ``floor`` / ``ceiling``: height above home ``h = z_home - z`` (NED z is down);
- predictive floor / ceiling / geofence: the position ``lookahead`` seconds ahead at the
  current velocity, ``p + v * lookahead``, must satisfy the same limits, i.e. the
  time-to-floor at the current descent rate must exceed ``lookahead`` (a vehicle sinking
  at 1.5 m/s with ``lookahead = 3`` trips 4.5 m above the floor, leaving room for the
  hand-back and for PX4 to brake);
- ``radius``: horizontal distance from home (geofence cylinder);
- ``max_tilt_deg``: angle between body z and NED z, ``acos(cos(phi) cos(theta))``;
- ``max_speed``: norm of the NED velocity;
- setpoints: every value finite, norm of the velocity reference <= ``max_setpoint``,
  ``|yaw rate| <= max_setpoint_yaw_rate`` (a 1e39 m/s reference cannot be packed into
  MAVLink's float32 and must never reach the encoder).

The floor must not trip on the ground before take-off: it is *inactive* until the
vehicle has been above ``floor + floor_arm_margin`` once (or :meth:`Envelope.activate_floor`
is called, e.g. by the campaign); the ceiling, fence, tilt, speed and setpoint checks are
active from :meth:`Envelope.arm`.

Home (``home``): ``auto`` (default) takes the vehicle position at arming when the vehicle
is disarmed then (on the ground before take-off: PX4 itself sets its home where it arms,
and the HOME_POSITION it streams before arming is the previous flight's), and PX4's
HOME_POSITION when the vehicle is already armed (a bridge started in the air needs it for
a floor that means "above the ground"; without it: the position at arming, with a
warning); ``home_position`` always takes HOME_POSITION and refuses to arm without it;
``start`` always takes the position at arming. Home never moves while armed.

A violation latches (:attr:`Envelope.violation`): the bridge hands control back to PX4 at
once and reports the reason as an error event; the envelope stays tripped until re-armed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.io import frames

HOME_MODES = ("auto", "home_position", "start")

FLOOR, CEILING, RADIUS, TILT, SPEED = "floor", "ceiling", "radius", "tilt", "speed"
SETPOINT, NON_FINITE, HOME = "setpoint", "non_finite", "home"
KINDS = (FLOOR, CEILING, RADIUS, TILT, SPEED, SETPOINT, NON_FINITE, HOME)


def _limit(default: float, doc: str, hi: float, unit: str, lo_open: bool = True) -> Any:
    """A positive limit of the envelope, at most ``hi`` (a larger one guards nothing)."""
    return cf.number(default, doc, lo=0.0, lo_open=lo_open, hi=hi, unit=unit)


@dataclass(frozen=True)
class EnvelopeConfig:
    """``envelope`` section of ``config/mavlink_bridge.yaml`` (module docstring), checked
    by :meth:`validate` (also for a config built in code: :class:`Envelope` calls it). The
    upper bounds keep every limit a guard: beyond them it no longer bounds a test flight."""

    enabled: bool = cf.flag(True, "enforce the envelope (violation -> hand-back)")
    home: str = cf.choice("auto", HOME_MODES, "where home is taken (module docstring)")
    floor: float = _limit(5.0, "floor above home [m]; at most 100 m", 100.0, " m", lo_open=False)
    ceiling: float = _limit(
        80.0,
        "ceiling above home [m]; at most 500 m (national limits are 120-150 m above ground)",
        500.0,
        " m",
    )
    floor_arm_margin: float = _limit(
        1.0,
        "the floor is active once above floor + margin [m]; at most 10 m: a larger margin "
        "leaves the floor off on a low flight",
        10.0,
        " m",
        lo_open=False,
    )
    lookahead: float = _limit(
        3.0,
        "predictive floor/ceiling/fence on p + v * lookahead [s]; at most 10 s",
        10.0,
        " s",
        lo_open=False,
    )
    radius: float = _limit(
        300.0,
        "horizontal geofence around home [m]; at most 2 km (a test flight stays in visual "
        "line of sight)",
        2000.0,
        " m",
    )
    max_tilt_deg: float = _limit(
        50.0,
        "largest tilt acos(cos(phi) cos(theta)) [deg]; at most 80 deg (PX4's MPC_TILTMAX_AIR "
        "is at most 89 deg; a multirotor cannot hold height near 90 deg)",
        80.0,
        " deg",
    )
    max_speed: float = _limit(
        12.0,
        "largest NED speed [m/s]; at most 30 m/s (PX4 MPC_XY_VEL_MAX <= 20 m/s)",
        30.0,
        " m/s",
    )
    max_setpoint: float = _limit(
        12.0,
        "velocity references above this are rejected [m/s]; at most 30 m/s",
        30.0,
        " m/s",
    )
    max_setpoint_yaw_rate: float = _limit(
        2.0,
        "yaw-rate references above this are rejected [rad/s]; at most one turn per second",
        2.0 * math.pi,
        " rad/s",
    )

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "envelope") -> "EnvelopeConfig":
        cfg = cls(**cf.parse_fields(cls, d, where))
        cfg.validate(where)
        return cfg

    def validate(self, where: str = "envelope") -> None:
        """The declared fields, then: the ceiling lies above the armed floor."""
        cf.check_fields(self, where)
        if self.ceiling <= self.floor + self.floor_arm_margin:
            raise cf.error(
                where,
                "ceiling",
                f"{self.ceiling} m must be above floor + floor_arm_margin "
                f"({self.floor} + {self.floor_arm_margin} m)",
            )


@dataclass(frozen=True)
class Violation:
    """Why the envelope tripped: ``kind`` is one of :data:`KINDS`."""

    t: float
    kind: str
    message: str


@dataclass(frozen=True)
class EnvelopeNotice:
    """Something worth reporting that is not a violation (home chosen, floor activated)."""

    t: float
    message: str
    level: str = "info"


class Envelope:
    """The checks of the module docstring; see :class:`EnvelopeConfig`."""

    def __init__(self, config: EnvelopeConfig | None = None) -> None:
        self.config = config or EnvelopeConfig()
        self.config.validate()
        self.armed = False
        self.home: np.ndarray | None = None  # NED
        self.home_source = ""
        self.home_position: np.ndarray | None = None  # latest HOME_POSITION (NED)
        self.floor_active = False
        self.violation: Violation | None = None
        self.height: float = math.nan
        self.distance: float = math.nan
        self.tilt_deg: float = math.nan
        self.speed: float = math.nan
        self._notices: list[EnvelopeNotice] = []

    @property
    def enabled(self) -> bool:
        return self.config.enabled

    # ------------------------------------------------------------------ lifecycle
    def set_home_position(self, pos_ned: Any) -> None:
        """PX4 HOME_POSITION (local NED x, y, z); used by the next :meth:`arm`."""
        p = np.asarray(pos_ned, dtype=float)
        if p.shape == (3,) and np.isfinite(p).all():
            self.home_position = p

    def arm(
        self, now: float, pos_ned: Any = None, vehicle_armed: bool = False
    ) -> Violation | None:
        """Start enforcing; home per ``config.home`` and ``vehicle_armed`` (module
        docstring). Without a position yet (no telemetry) the home is taken from the first
        state sample."""
        self.armed = True
        self.violation = None
        self.floor_active = False
        self.home = None
        self.home_source = ""
        if not self.enabled:
            return None
        mode = self.config.home
        use_hp = mode == "home_position" or (mode == "auto" and vehicle_armed)
        if use_hp and self.home_position is not None:
            self._set_home(now, self.home_position, "HOME_POSITION")
        elif mode == "home_position":
            return self._trip(
                now,
                HOME,
                "no HOME_POSITION received from the vehicle (envelope.home: home_position)",
            )
        elif pos_ned is not None:
            self._set_home(
                now,
                pos_ned,
                "position at start"
                + (
                    " (armed, but no HOME_POSITION received: heights are above this point)"
                    if use_hp
                    else ""
                ),
            )
            if use_hp:
                self._notices[-1] = EnvelopeNotice(now, self._notices[-1].message, "warn")
        return None

    def disarm(self) -> None:
        self.armed = False

    def activate_floor(self, now: float, reason: str = "requested") -> None:
        if not self.floor_active and self.enabled:
            self.floor_active = True
            self._notices.append(
                EnvelopeNotice(now, f"envelope: floor {self.config.floor:g} m active ({reason})")
            )

    def notices(self) -> list[EnvelopeNotice]:
        out, self._notices = self._notices, []
        return out

    # ------------------------------------------------------------------ checks
    def check_state(self, sample: Any) -> Violation | None:
        """One state sample (``t``, ``pos_ned``, ``euler``, ``v_body`` and optionally
        ``vel_ned``); returns the violation that tripped the envelope now, else None."""
        if not (self.enabled and self.armed) or self.violation is not None:
            return None
        t = float(sample.t)
        pos = np.asarray(sample.pos_ned, dtype=float)
        euler = np.asarray(sample.euler, dtype=float)
        vel = getattr(sample, "vel_ned", None)
        vel = (
            frames.body_to_world(sample.v_body, euler)
            if vel is None
            else np.asarray(vel, dtype=float)
        )
        if not (np.isfinite(pos).all() and np.isfinite(euler).all() and np.isfinite(vel).all()):
            return self._trip(t, NON_FINITE, "non-finite state sample")
        home = self.home
        if home is None:
            home = self._set_home(t, pos, "first state sample after start")
        cfg = self.config
        h = float(home[2] - pos[2])
        d = float(math.hypot(pos[0] - home[0], pos[1] - home[1]))
        T = cfg.lookahead
        pred = pos + vel * T
        h_pred = float(home[2] - pred[2])
        d_pred = float(math.hypot(pred[0] - home[0], pred[1] - home[1]))
        c = math.cos(euler[0]) * math.cos(euler[1])
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, c))))
        speed = float(np.linalg.norm(vel))
        self.height, self.distance, self.tilt_deg, self.speed = h, d, tilt, speed
        if not self.floor_active and h > cfg.floor + cfg.floor_arm_margin:
            self.activate_floor(
                t, f"airborne at {h:.1f} m > floor + margin {cfg.floor + cfg.floor_arm_margin:g} m"
            )
        if self.floor_active:
            if h < cfg.floor:
                return self._trip(t, FLOOR, f"height {h:.2f} m below the floor {cfg.floor:g} m")
            if h_pred < cfg.floor:
                rate = float(vel[2])
                return self._trip(
                    t,
                    FLOOR,
                    f"predictive floor: descending {rate:.2f} m/s at "
                    f"{h:.2f} m reaches the floor {cfg.floor:g} m in "
                    f"{(h - cfg.floor) / max(rate, 1e-9):.2f} s "
                    f"(< lookahead {T:g} s)",
                )
        if h > cfg.ceiling:
            return self._trip(t, CEILING, f"height {h:.2f} m above the ceiling {cfg.ceiling:g} m")
        if h_pred > cfg.ceiling:
            return self._trip(
                t,
                CEILING,
                f"predictive ceiling: climbing {-vel[2]:.2f} m/s at "
                f"{h:.2f} m reaches the ceiling {cfg.ceiling:g} m within "
                f"the lookahead {T:g} s",
            )
        if d > cfg.radius:
            return self._trip(
                t, RADIUS, f"{d:.1f} m from home, outside the geofence radius {cfg.radius:g} m"
            )
        if d_pred > cfg.radius:
            return self._trip(
                t,
                RADIUS,
                f"predictive geofence: {d:.1f} m from home, moving "
                f"{math.hypot(vel[0], vel[1]):.2f} m/s horizontally, "
                f"crosses the radius {cfg.radius:g} m within {T:g} s",
            )
        if tilt > cfg.max_tilt_deg:
            return self._trip(t, TILT, f"tilt {tilt:.1f} deg > max_tilt_deg {cfg.max_tilt_deg:g}")
        if speed > cfg.max_speed:
            return self._trip(t, SPEED, f"speed {speed:.2f} m/s > max_speed {cfg.max_speed:g} m/s")
        return None

    def check_setpoint(self, now: float, v: Any, yaw_rate: Any = 0.0) -> Violation | None:
        """A velocity reference (3 values, m/s) and yaw rate (rad/s): returns the
        violation (not latched here: the caller decides whether it trips) or None.
        Non-numeric or non-finite values are violations whether or not the envelope is
        enabled (they can never be sent)."""
        try:
            a = np.asarray(v, dtype=float)
            r = float(yaw_rate)
        except (TypeError, ValueError):
            return Violation(now, NON_FINITE, f"setpoint not numeric ({v!r}, {yaw_rate!r})")
        if a.shape != (3,):
            return Violation(now, NON_FINITE, f"setpoint needs 3 values, got shape {a.shape}")
        if not (np.isfinite(a).all() and math.isfinite(r)):
            return Violation(
                now, NON_FINITE, f"non-finite setpoint {a.tolist()!r}, yaw rate {r!r}"
            )
        if not self.enabled:
            return None
        n = float(np.linalg.norm(a))
        if n > self.config.max_setpoint:
            return Violation(
                now,
                SETPOINT,
                f"setpoint |v| = {n:.4g} m/s > max_setpoint {self.config.max_setpoint:g} m/s",
            )
        if abs(r) > self.config.max_setpoint_yaw_rate:
            return Violation(
                now,
                SETPOINT,
                f"yaw-rate setpoint {r:.4g} rad/s exceeds "
                f"max_setpoint_yaw_rate {self.config.max_setpoint_yaw_rate:g}",
            )
        return None

    def trip(self, violation: Violation) -> Violation:
        """Latch ``violation`` (e.g. a setpoint violation the caller acts upon)."""
        if self.violation is None:
            self.violation = violation
        return violation

    # ------------------------------------------------------------------ status
    def height_above_home(self, pos_ned: Any) -> float:
        if self.home is None:
            return math.nan
        return float(self.home[2] - float(np.asarray(pos_ned, dtype=float)[2]))

    def status(self) -> dict[str, str]:
        if not self.enabled:
            return {"envelope": "disabled"}
        state = "tripped" if self.violation else ("armed" if self.armed else "disarmed")
        d = {
            "envelope": state,
            "envelope_floor_active": str(self.floor_active),
            "envelope_home": (
                "unset"
                if self.home is None
                else f"{self.home_source}: " + " ".join(f"{v:.2f}" for v in self.home)
            ),
            "envelope_height_m": _fmt(self.height),
            "envelope_distance_m": _fmt(self.distance),
            "envelope_tilt_deg": _fmt(self.tilt_deg),
            "envelope_speed_m_s": _fmt(self.speed),
        }
        if self.violation is not None:
            d["envelope_violation"] = f"{self.violation.kind}: {self.violation.message}"
        return d

    # ------------------------------------------------------------------ internals
    def _set_home(self, now: float, pos: Any, source: str) -> np.ndarray:
        """Set and return the home position (NED, m)."""
        home = np.asarray(pos, dtype=float).copy()
        self.home = home
        self.home_source = source
        self._notices.append(
            EnvelopeNotice(
                now, f"envelope: home = {source} (NED {[round(float(x), 2) for x in home]})"
            )
        )
        return home

    def _trip(self, t: float, kind: str, message: str) -> Violation:
        return self.trip(Violation(t, kind, message))


def _fmt(v: float) -> str:
    return f"{v:.3f}" if math.isfinite(v) else "nan"
