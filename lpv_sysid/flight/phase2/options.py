"""Flight options of a phase-2 flight on PX4
(:func:`lpv_sysid.flight.phase2.sequence.fly_phase2`), declared once."""

from __future__ import annotations

import dataclasses
from typing import Optional

from lpv_sysid.configuration import fields as cf


@dataclasses.dataclass(frozen=True)
class Phase2Options:
    """Flight options of :func:`fly_phase2`.

    >>> Phase2Options(kappa=0.5).validate()
    >>> Phase2Options(max_tracking_error=0.0).validate()
    Traceback (most recent call last):
    ...
    lpv_sysid.errors.ConfigError: phase2.max_tracking_error: must be > 0, got 0.0
    """

    kappa: float = cf.number(1.0, "excitation multiplier (seed 0 Eq. 33)", lo=0.0, hi=100.0)
    control_rate_hz: float = cf.number(
        50.0,
        "law evaluations per second (on the newest state sample)",
        lo=0.0,
        lo_open=True,
        hi=1000.0,
        unit=" Hz",
    )
    ramp_s: float = cf.number(
        3.0, "raised-cosine fade of v_d and u_e at both ends", lo=0.0, hi=600.0, unit=" s"
    )
    lead_in_s: float = cf.number(
        2.0,
        "hover (v_d = 0) under the law before the signal starts",
        lo=0.0,
        hi=600.0,
        unit=" s",
    )
    duration: Optional[float] = cf.number(
        None,
        "seconds of the signal (null: one period)",
        lo=0.0,
        lo_open=True,
        unit=" s",
        optional=True,
    )
    max_tracking_error: float = cf.number(
        2.5, "|v - v_d| per axis -> hand back", lo=0.0, lo_open=True, hi=20.0, unit=" m/s"
    )
    start_timeout: float = cf.number(
        15.0, "for OFFBOARD to be confirmed", lo=0.0, lo_open=True, hi=120.0, unit=" s"
    )
    handback_timeout: float = cf.number(
        15.0,
        "for the hand-back mode to be confirmed",
        lo=0.0,
        lo_open=True,
        hi=120.0,
        unit=" s",
    )
    finish: str = cf.choice("LAND", ("LAND", "HOLD"), "mode after the signal", fold_case=True)
    max_rate: float = cf.number(
        2.0,
        "clip of the rate setpoints (transport)",
        lo=0.0,
        lo_open=True,
        hi=20.0,
        unit=" rad/s",
    )
    min_height: float = cf.number(8.0, "above home needed to start", lo=0.0, hi=1000.0, unit=" m")

    def validate(self) -> None:
        """The declared fields (ConfigError ``phase2.<field>: ...``)."""
        cf.check_fields(self, "phase2")
