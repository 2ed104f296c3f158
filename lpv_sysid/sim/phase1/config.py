"""Phase-1 experiment settings (seed 0 Sec. IV) and the configuration file that holds them
(``config/quadrotor.yaml``: sections quadrotor, controller, sim, phase1)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from lpv_sysid.configuration.fields import check_keys, is_count, is_finite_number
from lpv_sysid.control.baseline import BaselineGains
from lpv_sysid.errors import ConfigError
from lpv_sysid.io.files import read_yaml
from lpv_sysid.models.quadrotor import QuadrotorParams
from lpv_sysid.sim.vehicle import SensorConfig


@dataclass(frozen=True)
class Phase1Config:
    """Phase-1 experiment settings (seed 0 Sec. IV)."""

    box_min: tuple = (-5.0, -5.0, -5.0)
    box_max: tuple = (5.0, 5.0, 5.0)
    trim_s: float = 10.0
    excite_s: float = 30.0
    trim_average_s: float = 5.0
    amplitudes: tuple = (1.5, 1.5, 1.0, 0.4)  # peak u, v, w [m/s], yaw rate [rad/s]
    f_min_hz: float = 0.2
    f_max_hz: float = 2.0
    taper_s: float = 1.0
    hover_validation: bool = True
    start: str = (
        "hover"  # "hover": reference steps from hover at t=0; "trim": start at the model trim
    )
    seed: int = 0

    def __post_init__(self) -> None:
        if self.start not in ("hover", "trim"):
            raise ConfigError(f"phase1.start: must be 'hover' or 'trim', got {self.start!r}")
        for name, n in (("box_min", 3), ("box_max", 3), ("amplitudes", 4)):
            v = getattr(self, name)
            try:
                arr = np.asarray(v, dtype=float)
            except (TypeError, ValueError):
                raise ConfigError(f"phase1.{name}: not numeric: {v!r}") from None
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise ConfigError(f"phase1.{name}: expected {n} finite numbers, got {v!r}")
            object.__setattr__(self, name, tuple(float(x) for x in arr))
        if any(a >= b for a, b in zip(self.box_min, self.box_max)):
            raise ConfigError("phase1.box_min: must be below box_max in every component")
        if any(a < 0 for a in self.amplitudes):
            raise ConfigError("phase1.amplitudes: must be >= 0")
        from lpv_sysid.signals.multisine import MAX_DURATION

        for name in ("trim_s", "excite_s", "trim_average_s", "f_min_hz", "f_max_hz", "taper_s"):
            v = getattr(self, name)
            if not is_finite_number(v) or v < 0:
                raise ConfigError(f"phase1.{name}: must be a finite number >= 0, got {v!r}")
            if name.endswith("_s") and v > MAX_DURATION:  # simulated before anything is written
                raise ConfigError(
                    f"phase1.{name}: {v:g} s exceeds the limit of {MAX_DURATION:g} s"
                )
            object.__setattr__(self, name, float(v))
        if self.trim_s <= 0 or self.excite_s <= 0:
            raise ConfigError("phase1.trim_s and phase1.excite_s: must be > 0")
        if not 0 < self.f_min_hz < self.f_max_hz:
            raise ConfigError("phase1.f_min_hz: need 0 < f_min_hz < f_max_hz")
        if not isinstance(self.hover_validation, bool):
            raise ConfigError("phase1.hover_validation: must be true or false")
        if not is_count(self.seed):
            raise ConfigError(f"phase1.seed: must be a non-negative integer, got {self.seed!r}")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Phase1Config":
        check_keys(d, {f.name for f in fields(cls)}, "phase1")
        return cls(**d)

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
