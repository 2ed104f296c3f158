"""Phase-1 experiment settings (seed 0 Sec. IV) and the configuration file that holds them
(``config/quadrotor.yaml``: sections quadrotor, controller, sim, phase1)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Mapping

from lpv_sysid.configuration import fields as cf
from lpv_sysid.control.baseline import BaselineGains
from lpv_sysid.errors import ConfigError
from lpv_sysid.io.files import read_yaml
from lpv_sysid.models.quadrotor import QuadrotorParams
from lpv_sysid.signals.multisine import MAX_DURATION
from lpv_sysid.sim.vehicle import SensorConfig


def _duration(default: float, doc: str, lo_open: bool) -> Any:
    """A duration simulated before anything is written: at most MAX_DURATION (an hour)."""
    return cf.number(default, doc, lo=0.0, lo_open=lo_open, hi=MAX_DURATION, unit=" s")


@dataclass(frozen=True)
class Phase1Config:
    """Phase-1 experiment settings (seed 0 Sec. IV), checked on every construction."""

    box_min: tuple = cf.numbers((-5.0, -5.0, -5.0), "scheduling box low corner [m/s]", length=3)
    box_max: tuple = cf.numbers((5.0, 5.0, 5.0), "scheduling box high corner [m/s]", length=3)
    trim_s: float = _duration(10.0, "steady reference before the excitation [s]", True)
    excite_s: float = _duration(30.0, "excitation per vertex [s]", True)
    trim_average_s: float = _duration(5.0, "end of the trim averaged for x0, u0 [s]", False)
    amplitudes: tuple = cf.numbers(
        (1.5, 1.5, 1.0, 0.4), "peak u, v, w [m/s], yaw rate [rad/s]", length=4, lo=0.0
    )
    f_min_hz: float = cf.number(0.2, "excitation band low edge [Hz]", lo=0.0, lo_open=True)
    f_max_hz: float = cf.number(2.0, "excitation band high edge [Hz]", lo=0.0, lo_open=True)
    taper_s: float = _duration(1.0, "raised-cosine taper of the excitation [s]", False)
    hover_validation: bool = cf.flag(True, "fly the box centre as validation run")
    start: str = cf.choice(
        "hover",
        ("hover", "trim"),
        "hover: reference steps from hover at t=0; trim: start at the model trim",
    )
    seed: int = cf.count(0, "noise seed")

    def __post_init__(self) -> None:
        """The declared fields, then: box_min below box_max, f_min_hz below f_max_hz."""
        cf.normalize_fields(self, "phase1")
        if any(a >= b for a, b in zip(self.box_min, self.box_max)):
            raise cf.error("phase1", "box_min", "must be below box_max in every component")
        if not self.f_min_hz < self.f_max_hz:
            raise cf.error("phase1", "f_min_hz", f"must be below f_max_hz ({self.f_max_hz})")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "phase1") -> "Phase1Config":
        return cls(**cf.parse_fields(cls, d, where))

    def scaled(self, s: float) -> "Phase1Config":
        """Durations multiplied by ``s`` (quick runs); the band is kept."""
        if not (math.isfinite(s) and s > 0):
            raise ConfigError(f"duration scale must be > 0, got {s}")
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        for name in ("trim_s", "excite_s", "trim_average_s", "taper_s"):
            kw[name] = kw[name] * s
        return Phase1Config(**kw)

    def vertices(self) -> list[tuple[float, float, float]]:
        """The 2^3 box corners in seed 0 Table 1 order (u fastest, then v, then w)."""
        return [
            (u, v, w)
            for w, v, u in itertools.product(
                (self.box_min[2], self.box_max[2]),
                (self.box_min[1], self.box_max[1]),
                (self.box_min[0], self.box_max[0]),
            )
        ]


def load_config(
    path: str | Path,
) -> tuple[QuadrotorParams, BaselineGains, SensorConfig, Phase1Config]:
    """Read config/quadrotor.yaml (sections quadrotor, controller, sim, phase1)."""
    p = Path(path)
    d = read_yaml(p)
    if not isinstance(d, dict):
        raise ConfigError(f"{p}: expected a mapping at top level")
    allowed = {"quadrotor", "controller", "sim", "phase1", "phase2"}
    bad = sorted(set(d) - allowed)
    if bad:
        raise ConfigError(f"{p}: unknown section(s) {bad}; allowed: {sorted(allowed)}")
    try:
        qp = QuadrotorParams.from_dict(d.get("quadrotor") or {})
        gains = BaselineGains.from_dict(d.get("controller") or {})
        sens = SensorConfig.from_dict(d.get("sim") or {})
        ph1 = Phase1Config.from_dict(d.get("phase1") or {})
    except TypeError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    except ConfigError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    return qp, gains, sens, ph1
