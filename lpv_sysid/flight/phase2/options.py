"""Flight options of a phase-2 flight on PX4
(:func:`lpv_sysid.flight.phase2.sequence.fly_phase2`)."""

from __future__ import annotations

import dataclasses
from typing import Optional

from lpv_sysid.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class Phase2Options:
    """Flight options of :func:`fly_phase2`."""

    kappa: float = 1.0  # excitation multiplier (seed 0 Eq. 33)
    control_rate_hz: float = 50.0  # law evaluations per second (on the newest state sample)
    ramp_s: float = 3.0  # raised-cosine fade of v_d and u_e at both ends
    lead_in_s: float = 2.0  # hover (v_d = 0) under the law before the signal starts
    duration: Optional[float] = None  # s of the signal (None: one period)
    max_tracking_error: float = 2.5  # m/s |v - v_d| per axis -> hand back
    start_timeout: float = 15.0  # s for OFFBOARD to be confirmed
    handback_timeout: float = 15.0
    finish: str = "LAND"  # mode after the signal (LAND | HOLD)
    max_rate: float = 2.0  # rad/s clip of the rate setpoints (transport)
    min_height: float = 8.0  # m above home needed to start

    def validate(self) -> None:
        if not (
            self.kappa >= 0
            and self.control_rate_hz > 0
            and self.ramp_s >= 0
            and self.lead_in_s >= 0
            and self.max_tracking_error > 0
            and self.max_rate > 0
        ):
            raise ConfigError(f"phase 2 options out of range: {self}")
        if self.finish.upper() not in ("LAND", "HOLD"):
            raise ConfigError(f"phase 2 finish must be LAND or HOLD, got {self.finish!r}")
