"""Options of the runtime LPV law (:class:`LpvControllerConfig`, the ``lpv_controller`` section
of the node config): one frozen dataclass that validates itself on every construction (node,
replay, simulation, library), so a config that exists is one the law of
:mod:`lpv_sysid.control.law.controller` can fly."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError

#: the excitation multiplier kappa (seed 0 Eq. 33): the one declared range, used by the
#: controller node (``excitation_gain``), the phase-2 simulation and every command that
#: takes ``--kappa`` (checked before anything runs)
KAPPA_MIN, KAPPA_MAX = 0.0, 10.0


def check_kappa(kappa, where: str = "--kappa", positive: bool = False) -> float:
    """``kappa`` as a float in [KAPPA_MIN, KAPPA_MAX] (``positive``: > 0), else ConfigError
    naming ``where``."""
    try:
        k = float(kappa)
    except (TypeError, ValueError):
        raise ConfigError(f"{where} {kappa!r}: not a number") from None
    ok = KAPPA_MIN <= k <= KAPPA_MAX and (k > 0 or not positive)
    if not ok:  # NaN fails both comparisons
        lo = f"> {KAPPA_MIN:g}" if positive else f">= {KAPPA_MIN:g}"
        raise ConfigError(
            f"{where} {kappa!r}: the excitation multiplier (seed 0 Eq. 33) must be {lo} and "
            f"<= {KAPPA_MAX:g}"
        )
    return k


@dataclass(frozen=True)
class LpvControllerConfig:
    """Options of the runtime law (``lpv_controller`` section of the node config), checked on
    every construction (node, replay, simulation, library): a config that exists is one the
    law can fly. The node's parameters
    (:class:`~lpv_sysid.flight.controller.settings.ControllerSettings`) declare the same
    ranges; a rate limit below 0.01 /s is refused here."""

    u_esc_min: float = cf.number(0.0, "lower ESC command limit, in [0, 1]", lo=0.0, hi=1.0)
    u_esc_max: float = cf.number(1.0, "upper ESC command limit, in [0, 1]", lo=0.0, hi=1.0)
    rate_limit: Optional[tuple] = cf.numbers(
        None,
        "per virtual channel, units of u per second (null: none); 0.01 .. 1000 /s: a "
        "slower limit freezes the command (u_a, u_e are ~0.01-0.1 m, u_t in [0, 1])",
        lo=0.01,
        hi=1000.0,
        optional=True,
    )
    monitor_margin: float = cf.number(
        1.2,
        "bound monitor: flag when gain > gamma x margin; 1 .. 10 (a larger margin never "
        "flags: no bound is monitored)",
        lo=1.0,
        hi=10.0,
    )
    monitor_min_energy: float = cf.number(
        0.05,
        "||u_e||_2^2 needed before the gain is judged; at most 1 (the design signal's energy "
        "per period, Eq. 26: a larger one is never reached)",
        lo=0.0,
        lo_open=True,
        hi=1.0,
    )
    velocity_index: tuple = cf.counts((2, 3, 4), "u, v, w in the 12-state of DESIGN.md")
    feedforward: bool = cf.flag(True, "use the schedule's F_ff when it has one")
    ff_filter_tau: float = cf.number(
        0.05, "derivative filter of v_d when a is not given [s]", lo=0.0, hi=2.0, unit=" s"
    )
    ff_jerk_tau: float = cf.number(
        0.2, "second stage (jerk) filter when j is not given [s]", lo=0.0, hi=5.0, unit=" s"
    )
    monitor_window: Optional[float] = cf.number(
        None,
        "exponential forgetting of the monitor [s] (null: running); 1 .. 10000 s: a shorter "
        "window judges the gain on noise",
        lo=1.0,
        hi=1e4,
        unit=" s",
        optional=True,
    )

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """The declared fields, then: u_esc_min below u_esc_max."""
        cf.normalize_fields(self, "lpv_controller")
        if not self.u_esc_min < self.u_esc_max:
            raise cf.error(
                "lpv_controller",
                "u_esc_min",
                f"need u_esc_min < u_esc_max, got {self.u_esc_min:g} >= {self.u_esc_max:g}",
            )

    @classmethod
    def from_dict(cls, d: Optional[dict], where: str = "lpv_controller") -> "LpvControllerConfig":
        return cls(**cf.parse_fields(cls, d or {}, where))
