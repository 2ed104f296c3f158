"""The ``campaign`` section of ``config/campaign.yaml``: :class:`CampaignConfig` and its
checks (the sequence these settings drive is described in :mod:`lpv_sysid.control.campaign`)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Mapping

from lpv_sysid.configuration import fields as cf

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


#: largest height above home [m] the campaign may plan: the envelope ceiling's limit
MAX_ALTITUDE = 500.0


def _timeout(default: float, doc: str, hi: float) -> Any:
    """A phase timeout [s] > 0, at most ``hi``: a larger one waits on a stuck phase forever."""
    return cf.number(default, doc, lo=0.0, lo_open=True, hi=hi, unit=" s")


def _positive(default: float, doc: str, hi: float, unit: str) -> Any:
    return cf.number(default, doc, lo=0.0, lo_open=True, hi=hi, unit=unit)


# =============================================================================== config
@dataclass(frozen=True)
class CampaignConfig:
    """``campaign`` section of ``config/campaign.yaml`` (heights above home, m; m/s; s),
    checked by :meth:`validate` (also for a config built in code: the planner calls it).

    The limits keep every guard a guard: speeds within PX4's own ranges (MPC_*_VEL_MAX),
    heights and radius within the envelope's, timeouts bounded so a stuck phase ends."""

    box_min: tuple = cf.numbers(
        (-3.0, -3.0, -0.7), "body-velocity box low corner (u, v, w) [m/s]", length=3
    )
    box_max: tuple = cf.numbers((3.0, 3.0, 0.7), "body-velocity box high corner [m/s]", length=3)
    vertices: tuple | None = cf.counts(
        None,
        "seed 0 Table 1 indices 1..8 to fly (null: all 8)",
        lo=1,
        hi=8,
        unique=True,
        optional=True,
    )
    hover_validation: bool = cf.flag(True, "extra run at the box centre")
    order: str = cf.choice("alternate", ORDERS, "alternate climbs/descents | table order")
    velocity_frame: str = cf.choice(
        "body_ned",
        FRAMES,
        "the bridge's velocity_frame; body_ned only: with local_ned the bridge rotates the "
        "FRD vertex by the full attitude, so a w = 0 vertex sinks u sin(theta) at pitch "
        "theta and no altitude hold can keep the vertex",
    )
    rate_hz: float = cf.number(
        50.0,
        "velocity reference rate [Hz]; PX4 needs > 2 Hz, at most 1000 Hz",
        lo=2.0,
        lo_open=True,
        hi=1000.0,
        unit=" Hz",
    )
    takeoff_altitude: float = _positive(20.0, "take-off height [m]", MAX_ALTITUDE, " m")
    altitude_min: float = cf.number(
        15.0, "campaign altitude window, low [m]", lo=0.0, hi=MAX_ALTITUDE, unit=" m"
    )
    altitude_max: float = _positive(
        70.0,
        f"campaign altitude window, high [m]; at most {MAX_ALTITUDE:g} m (the envelope "
        "ceiling's limit)",
        MAX_ALTITUDE,
        " m",
    )
    altitude_margin: float = cf.number(
        2.0, "kept free at both ends of every segment [m]", lo=0.0, hi=50.0, unit=" m"
    )
    altitude_tolerance: float = _positive(
        1.0, "a target height is reached within this [m]; at most 10 m", 10.0, " m"
    )
    position_tolerance: float = _positive(
        3.0, "a horizontal start point is reached within this [m]; at most 50 m", 50.0, " m"
    )
    climb_rate: float = _positive(
        1.5, "take-off / reposition climb limit [m/s] (PX4 MPC_Z_VEL_MAX_UP <= 8)", 8.0, " m/s"
    )
    descent_rate: float = _positive(
        1.0, "reposition descent limit [m/s] (PX4 MPC_Z_VEL_MAX_DN <= 4)", 4.0, " m/s"
    )
    horizontal_speed: float = _positive(
        3.0, "reposition speed limit [m/s] (PX4 MPC_XY_VEL_MAX <= 20)", 20.0, " m/s"
    )
    position_gain: float = _positive(
        0.5, "take-off / reposition P loop [1/s]; at most 5", 5.0, " 1/s"
    )
    hold_gain: float = _positive(0.2, "altitude hold on level runs [1/s]; at most 5", 5.0, " 1/s")
    hold_max: float = cf.number(
        0.2,
        f"largest altitude-hold correction [m/s]; below {IDENTIFY_SNAP_TOLERANCE} m/s: the "
        "correction is part of the recorded trim reference that `lpv-sysid identify` snaps "
        "to the box",
        lo=0.0,
        lo_open=True,
        hi=IDENTIFY_SNAP_TOLERANCE,
        hi_open=True,
        unit=" m/s",
    )
    radius: float = _positive(
        250.0,
        "campaign horizontal limit around home [m]; at most 2 km (the envelope's)",
        2000.0,
        " m",
    )
    center_runs: bool = cf.flag(True, "reposition so each run is centred on home")
    drag_estimate: float = cf.number(
        1.0,
        "mass-normalised horizontal drag of the vehicle [1/s] (a prior, e.g. SIH_KDV / "
        "SIH_MASS), only for the tilt the box needs (preflight: MPC_TILTMAX_AIR)",
        lo=0.0,
        hi=10.0,
        unit=" 1/s",
    )
    settle_tolerance: tuple = cf.numbers(
        (0.3, 0.3, 0.3),
        "|measured - commanded| per axis for settled [m/s]; at most 2 m/s",
        length=3,
        lo=0.0,
        lo_open=True,
        hi=2.0,
    )
    settle_dwell: float = _timeout(1.0, "inside the tolerance this long = settled [s]", 60.0)
    settle_timeout: float = _timeout(20.0, "not settled within this -> abort [s]", 300.0)
    hover_tolerance: float = _positive(
        0.3, "speed below which hover is regained (take-off, recover) [m/s]", 2.0, " m/s"
    )
    trim_s: float = _timeout(10.0, "constant vertex reference before the excitation [s]", 3600.0)
    trim_average_s: float = _timeout(
        5.0, "end of the trim averaged for the equilibrium [s]", 3600.0
    )
    ramp_s: float = cf.number(
        1.0, "excitation raised-cosine ramps [s]", lo=0.0, hi=60.0, unit=" s"
    )
    periods: int = cf.count(1, "excitation periods per run", lo=1, hi=100)
    start_timeout: float = _timeout(
        20.0, "pre-stream + OFFBOARD + arming within this [s]; at most 120 s", 120.0
    )
    takeoff_timeout: float = _timeout(60.0, "take-off within this [s]; at most 600 s", 600.0)
    reposition_timeout: float = _timeout(90.0, "reposition within this [s]; at most 600 s", 600.0)
    recover_timeout: float = _timeout(20.0, "hover regained within this [s]; at most 120 s", 120.0)
    state_timeout: float = _timeout(
        0.5,
        "no state sample for longer -> abort [s]; at most 1 s: flying on an older state is "
        "flying blind",
        1.0,
    )
    handback_timeout: float = _timeout(
        15.0, "hand-back confirmed within this [s]; at most 120 s", 120.0
    )
    finish: str = cf.choice(
        "LAND", FINISH_MODES, "LAND (wait for disarm) | HOLD at the end", fold_case=True
    )
    land_timeout: float = _timeout(
        180.0, "landed and disarmed within this [s]; at most 900 s", 900.0
    )
    arm_length: float | None = cf.number(
        None,
        "for the Table 1 delta columns [m]; null: the quadrotor default",
        lo=0.0,
        lo_open=True,
        optional=True,
    )

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "campaign") -> "CampaignConfig":
        cfg = cls(**cf.parse_fields(cls, d, where))
        cfg.validate(where)
        return cfg

    def validate(self, where: str = "campaign") -> None:
        """The declared fields, then: the box, the altitude window holding the take-off
        height, the trim average within the trim, the dwell within the settle timeout."""
        cf.check_fields(self, where)
        if any(a >= b for a, b in zip(self.box_min, self.box_max)):
            raise cf.error(
                where,
                "box_min",
                f"{list(self.box_min)} must be below box_max {list(self.box_max)} in every "
                "component",
            )
        if self.altitude_min >= self.altitude_max:
            raise cf.error(
                where,
                "altitude_min",
                f"{self.altitude_min} m must be below altitude_max ({self.altitude_max} m)",
            )
        if not self.altitude_min <= self.takeoff_altitude <= self.altitude_max:
            raise cf.error(
                where,
                "takeoff_altitude",
                f"{self.takeoff_altitude} m must lie in the window "
                f"[{self.altitude_min}, {self.altitude_max}] m",
            )
        if self.trim_average_s > self.trim_s:
            raise cf.error(
                where,
                "trim_average_s",
                f"{self.trim_average_s} s must not exceed trim_s ({self.trim_s} s)",
            )
        if self.settle_dwell >= self.settle_timeout:
            raise cf.error(
                where,
                "settle_dwell",
                f"{self.settle_dwell} s must be shorter than settle_timeout "
                f"({self.settle_timeout} s)",
            )

    def corners(self) -> list[tuple[float, float, float]]:
        """The 2^3 box corners in seed 0 Table 1 order (u fastest, then v, then w)."""
        lo, hi = self.box_min, self.box_max
        return [
            (u, v, w)
            for w, v, u in itertools.product((lo[2], hi[2]), (lo[1], hi[1]), (lo[0], hi[0]))
        ]
