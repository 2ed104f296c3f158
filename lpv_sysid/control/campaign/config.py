"""The ``campaign`` section of ``config/campaign.yaml``: :class:`CampaignConfig` and its
checks (the sequence these settings drive is described in :mod:`lpv_sysid.control.campaign`)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, fields
from typing import Any, Mapping

from lpv_sysid.configuration.fields import check_keys, is_count, is_finite_number
from lpv_sysid.errors import ConfigError

#: the campaign commands in MAV_FRAME_BODY_NED (PX4 rotates by yaw only; seed 0's frame). In
#: ``local_ned`` the bridge rotates an FRD body reference by the full attitude, so a w = 0
#: vertex is not level flight: at pitch theta it sinks u sin(theta) (issue 10: 0.7-1.1 m/s,
#: into the ground), and holding altitude would move the recorded reference off the vertex.
FRAMES = ("body_ned",)
FINISH_MODES = ("LAND", "HOLD")
ORDERS = ("alternate", "table")
#: tolerance [m/s] with which ``lpv-sysid identify`` snaps a trim reference to the box
#: (lpv_sysid.ident.dataprep.snap_to_box)
IDENTIFY_SNAP_TOLERANCE = 0.25


# =============================================================================== config
@dataclass(frozen=True)
class CampaignConfig:
    """``campaign`` section of ``config/campaign.yaml`` (heights above home, m; m/s; s)."""

    box_min: tuple = (-3.0, -3.0, -0.7)
    box_max: tuple = (3.0, 3.0, 0.7)
    vertices: tuple | None = None  # 1-based seed 0 Table 1 indices; None: all 8
    hover_validation: bool = True
    order: str = "alternate"  # alternate | table
    velocity_frame: str = "body_ned"  # the bridge's velocity_frame (body_ned only, see FRAMES)
    rate_hz: float = 50.0  # velocity reference rate
    takeoff_altitude: float = 20.0
    altitude_min: float = 15.0  # campaign altitude window
    altitude_max: float = 70.0
    altitude_margin: float = 2.0  # kept free at both ends of every segment
    altitude_tolerance: float = 1.0  # reached a target height
    position_tolerance: float = 3.0  # reached a horizontal start point
    climb_rate: float = 1.5  # take-off / reposition limits
    descent_rate: float = 1.0
    horizontal_speed: float = 3.0
    position_gain: float = 0.5  # 1/s, take-off / reposition P loop
    hold_gain: float = 0.2  # 1/s, altitude hold on level runs
    hold_max: float = 0.2  # m/s
    radius: float = 250.0  # m, campaign horizontal limit around home
    center_runs: bool = True  # reposition so each run is centred on home
    settle_tolerance: tuple = (0.3, 0.3, 0.3)
    settle_dwell: float = 1.0
    settle_timeout: float = 20.0
    hover_tolerance: float = 0.3  # m/s speed: hover reached (take-off, recover)
    trim_s: float = 10.0
    trim_average_s: float = 5.0  # end of the trim averaged for the equilibrium
    ramp_s: float = 1.0  # excitation raised-cosine ramps
    periods: int = 1  # excitation periods per run
    start_timeout: float = 20.0
    takeoff_timeout: float = 60.0
    reposition_timeout: float = 90.0
    recover_timeout: float = 20.0
    state_timeout: float = 0.5
    handback_timeout: float = 15.0
    finish: str = "LAND"  # LAND | HOLD
    land_timeout: float = 180.0
    arm_length: float | None = None  # m, for the Table 1 delta columns; None: quadrotor default

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CampaignConfig":
        check_keys(d, {f.name for f in fields(cls)}, "campaign", list_allowed=True)
        kw = dict(d)
        for name in ("box_min", "box_max", "settle_tolerance", "vertices"):
            if name in kw and isinstance(kw[name], list):
                kw[name] = tuple(kw[name])
        cfg = cls(**kw)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        def num(name: str, lo: float = 0.0, strict: bool = True) -> None:
            v = getattr(self, name)
            if not is_finite_number(v) or (v <= lo if strict else v < lo):
                raise ConfigError(
                    f"campaign.{name} must be a finite number {'>' if strict else '>='} "
                    f"{lo:g}, got {v!r}"
                )

        for name, n in (("box_min", 3), ("box_max", 3), ("settle_tolerance", 3)):
            v = getattr(self, name)
            if not (isinstance(v, tuple) and len(v) == n and all(is_finite_number(x) for x in v)):
                raise ConfigError(f"campaign.{name} must be {n} finite numbers, got {v!r}")
        if any(a >= b for a, b in zip(self.box_min, self.box_max)):
            raise ConfigError(
                f"campaign.box_min {list(self.box_min)} must be below box_max "
                f"{list(self.box_max)} in every component"
            )
        if any(x <= 0 for x in self.settle_tolerance):
            raise ConfigError("campaign.settle_tolerance must be positive")
        if self.vertices is not None:
            v = self.vertices
            if not (
                isinstance(v, tuple)
                and v
                and all(is_count(i, 1) and i <= 8 for i in v)
                and len(set(v)) == len(v)
            ):
                raise ConfigError(
                    f"campaign.vertices must be distinct seed 0 Table 1 indices 1..8, got {v!r}"
                )
        for name in ("hover_validation", "center_runs"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"campaign.{name} must be true or false")
        if self.order not in ORDERS:
            raise ConfigError(f"campaign.order must be one of {list(ORDERS)}, got {self.order!r}")
        if self.velocity_frame not in FRAMES:
            raise ConfigError(
                f"campaign.velocity_frame must be 'body_ned', got {self.velocity_frame!r}: with "
                "local_ned the bridge rotates the FRD vertex by the full attitude, so a w = 0 "
                "vertex "
                "sinks u sin(theta) at pitch theta and no altitude hold can keep the vertex"
            )
        if str(self.finish).upper() not in FINISH_MODES:
            raise ConfigError(
                f"campaign.finish must be one of {list(FINISH_MODES)}, got {self.finish!r}"
            )
        for name in (
            "rate_hz",
            "takeoff_altitude",
            "altitude_max",
            "altitude_tolerance",
            "position_tolerance",
            "climb_rate",
            "descent_rate",
            "horizontal_speed",
            "position_gain",
            "hold_gain",
            "hold_max",
            "radius",
            "settle_dwell",
            "settle_timeout",
            "hover_tolerance",
            "trim_s",
            "trim_average_s",
            "start_timeout",
            "takeoff_timeout",
            "reposition_timeout",
            "recover_timeout",
            "state_timeout",
            "handback_timeout",
            "land_timeout",
        ):
            num(name)
        for name in ("altitude_min", "altitude_margin", "ramp_s"):
            num(name, strict=False)
        if not is_count(self.periods, 1):
            raise ConfigError(f"campaign.periods must be an integer >= 1, got {self.periods!r}")
        if self.arm_length is not None:
            num("arm_length")
        if self.altitude_min >= self.altitude_max:
            raise ConfigError(
                f"campaign.altitude_min ({self.altitude_min} m) must be below "
                f"altitude_max ({self.altitude_max} m)"
            )
        if not self.altitude_min <= self.takeoff_altitude <= self.altitude_max:
            raise ConfigError(
                f"campaign.takeoff_altitude {self.takeoff_altitude} m must lie in the "
                f"window [{self.altitude_min}, {self.altitude_max}] m"
            )
        if self.hold_max >= IDENTIFY_SNAP_TOLERANCE:
            raise ConfigError(
                f"campaign.hold_max {self.hold_max} m/s must stay below "
                f"{IDENTIFY_SNAP_TOLERANCE} m/s: the altitude correction is part of the "
                "recorded trim reference that `lpv-sysid identify` snaps to the box"
            )
        if self.trim_average_s > self.trim_s:
            raise ConfigError(
                f"campaign.trim_average_s ({self.trim_average_s} s) must not exceed "
                f"trim_s ({self.trim_s} s)"
            )
        if self.settle_dwell >= self.settle_timeout:
            raise ConfigError(
                f"campaign.settle_dwell ({self.settle_dwell} s) must be shorter than "
                f"settle_timeout ({self.settle_timeout} s)"
            )

    def corners(self) -> list[tuple[float, float, float]]:
        """The 2^3 box corners in seed 0 Table 1 order (u fastest, then v, then w)."""
        lo, hi = self.box_min, self.box_max
        return [
            (u, v, w)
            for w, v, u in itertools.product((lo[2], hi[2]), (lo[1], hi[1]), (lo[0], hi[0]))
        ]
