"""Options of the runtime LPV law (:class:`LpvControllerConfig`, the ``lpv_controller`` section
of the node config): one frozen dataclass that validates itself on every construction (node,
replay, simulation, library), so a config that exists is one the law of
:mod:`lpv_sysid.control.law.controller` can fly."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from lpv_sysid.configuration.fields import is_finite_number
from lpv_sysid.errors import ConfigError


@dataclass(frozen=True)
class LpvControllerConfig:
    """Options of the runtime law (``lpv_controller`` section of the node config), checked by
    :meth:`validate` on every construction."""

    u_esc_min: float = 0.0
    u_esc_max: float = 1.0
    rate_limit: Optional[tuple] = None  # per virtual channel, units of u per second
    monitor_margin: float = 1.2  # flag when gain > gamma * margin (>= 1)
    monitor_min_energy: float = 0.05  # ||u_e||_2^2 needed before the gain is judged
    velocity_index: tuple = (2, 3, 4)  # u, v, w in the 12-state of DESIGN.md
    feedforward: bool = True  # use the schedule's F_ff when it has one
    ff_filter_tau: float = 0.05  # s, derivative filter of v_d when a is not given
    ff_jerk_tau: float = 0.2  # s, second stage (jerk) filter when j is not given
    monitor_window: Optional[float] = (
        None  # s, exponential forgetting of the monitor (None: running)
    )

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Every rule, for every construction (node, replay, simulation, library): a config
        that exists is one the law can fly."""

        def bad(msg: str):
            raise ConfigError(f"lpv_controller: {msg}")

        def num(name: str, lo: float, hi: float = math.inf, lo_open: bool = False) -> float:
            v = getattr(self, name)
            if not is_finite_number(v) or (v <= lo if lo_open else v < lo) or v > hi:
                rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
                bad(f"{name} must be a finite number in {rng}, got {v!r}")
            return float(v)

        lo, hi = num("u_esc_min", 0.0, 1.0), num("u_esc_max", 0.0, 1.0)
        if not lo < hi:
            bad(f"need u_esc_min < u_esc_max, got {lo:g} >= {hi:g}")
        num("monitor_margin", 1.0)
        num("monitor_min_energy", 0.0, lo_open=True)
        num("ff_filter_tau", 0.0)
        num("ff_jerk_tau", 0.0)
        if self.monitor_window is not None:
            num("monitor_window", 0.0, lo_open=True)
        if self.rate_limit is not None:
            if not all(is_finite_number(r) and r > 0 for r in self.rate_limit):
                bad(
                    f"rate_limit entries must be finite and > 0 (units of u per second), "
                    f"got {list(self.rate_limit)}"
                )
        if not isinstance(self.feedforward, bool):
            bad(f"feedforward must be true or false, got {self.feedforward!r}")
        if not all(
            isinstance(i, (int, np.integer)) and not isinstance(i, bool) and i >= 0
            for i in self.velocity_index
        ):
            bad(f"velocity_index must be state indices, got {self.velocity_index!r}")

    @classmethod
    def from_dict(cls, d: Optional[dict]) -> "LpvControllerConfig":
        d = dict(d or {})
        bad = set(d) - set(cls.__dataclass_fields__)
        if bad:
            raise ConfigError(f"lpv_controller: unknown key(s) {sorted(bad)}")
        if "rate_limit" in d and d["rate_limit"] is not None:
            d["rate_limit"] = tuple(d["rate_limit"])
        if "velocity_index" in d:
            d["velocity_index"] = tuple(d["velocity_index"])
        return cls(**d)
