"""``config/identification.yaml``: the configuration of the vertex identification
(:mod:`lpv_sysid.ident.vertex`, seed 0 Sec. IV) and the vehicle parameters it names."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from lpv_sysid.configuration import fields as cf
from lpv_sysid.ident import derivatives as deriv
from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident.vertex import uncertainty as unc
from lpv_sysid.models.quadrotor import STATE_NAMES, QuadrotorParams
from lpv_sysid.signals.multisine import MAX_SAMPLE_RATE

#: channels of ``measurement_noise``: the states (STATE_NAMES) and the rotor speeds
NOISE_CHANNELS = (*STATE_NAMES, "rotor")


def _seconds(default: float, doc: str) -> Any:
    return cf.number(default, doc, lo=0.0, unit=" s")


@dataclass(frozen=True)
class IdentificationConfig:
    """``config/identification.yaml`` (all sections optional)."""

    derivatives: deriv.DerivativeConfig = field(default_factory=deriv.DerivativeConfig)
    uncertainty: unc.UncertaintyConfig = field(default_factory=unc.UncertaintyConfig)
    trim_duration: float = _seconds(
        10.0, "steady reference before the excitation [s] (seed 0 Sec. IV)"
    )
    trim_average: float = _seconds(5.0, "end of the trim segment averaged for x0, u0 [s]")
    edge: float = _seconds(0.5, "dropped at both ends of the fit segment [s] (end effects)")
    min_fit_duration: float = _seconds(5.0, "shorter excitation segments are refused [s]")
    sample_rate: float = cf.number(
        100.0,
        f"common grid of dataprep [Hz]; at most {MAX_SAMPLE_RATE:g} Hz (it is allocated)",
        lo=0.0,
        lo_open=True,
        hi=MAX_SAMPLE_RATE,
        unit=" Hz",
    )
    max_lag: int | None = cf.count(
        None, "residual autocorrelation lags (covariance.method residual_acf)", optional=True
    )
    intercept: bool = cf.flag(True, "per-row bias term (Klein & Morelli), see equation_error")
    model: str = cf.choice(
        "taylor2",
        ("taylor2", "appendix_b"),
        "taylor2 (ident.taylor) or appendix_b (plain seed 0 App. B)",
    )
    covariance: ee.CovarianceConfig = field(default_factory=ee.CovarianceConfig)
    equilibrium: bool = cf.flag(
        True, "taylor2: re-expand about the identified equilibrium (Eq. 13)"
    )
    fixed_intervals: bool = cf.flag(
        True,
        "taylor2 with equilibrium: the known elements that move with the identified "
        "equilibrium (gravity/kinematic terms at the identified attitude, rigid-body terms at "
        "the identified rotor speeds) get intervals from its delta-method uncertainty "
        "(issue 20 item 3); false: they are exact",
    )
    interpolation_pad: bool = cf.flag(
        True,
        "taylor2: measure the multilinear interpolation error between the vertices with the "
        "identified models re-expanded on a grid (ident/vertex/interpolation.py) and record "
        "it as meta.interpolation (the synthesis box adds it, issue 20 item 2)",
    )
    expand_at: str = cf.choice(
        "commanded",
        ("commanded", "flown"),
        "taylor2 with equilibrium: the velocity of the equilibrium the vertex model is expanded "
        "about: commanded (the vertex v_d the LPV model is scheduled on, issue 20 item 1) or "
        "flown (the mean velocity of the trim window; up to 0.26 m/s off v_d)",
    )
    motor: str = cf.choice(
        "identify",
        ("identify", "known"),
        "a_Omega, b_Omega: identify (motor rows, Eq. 8) or known",
    )
    motor_max_pinned: float = cf.number(
        0.01,
        "identify a_Omega, b_Omega only if no rotor is pinned at a speed limit longer than "
        "this fraction of the fit segment, in [0, 1]",
        lo=0.0,
        hi=1.0,
    )
    motor_std: tuple[float, float] | None = cf.numbers(
        None,
        "[std a_Omega, std b_Omega] where not identifiable (null: none)",
        length=2,
        lo=0.0,
        lo_open=True,
        optional=True,
    )
    instruments: bool = cf.flag(
        False, "taylor2: rotor speeds instrumented by the motor model (EIV check)"
    )
    motor_instrument: bool = cf.flag(
        True, "motor rows: measured speeds instrumented by the model's (EIV)"
    )
    measurement_noise: dict = cf.table(
        {},
        "EIV: channel (a state or rotor): std per sample, or [std, rate_hz] (rate the "
        "channel was sampled at; default the grid rate)",
        item=cf.FieldSpec(cf.NUMBERS, lo=0.0, length=(1, 2), scalar=True),
        choices=NOISE_CHANNELS,
        nullable=True,
    )
    excitation_threshold: float = cf.number(
        1e-6, "|u_e| above which the excitation counts as on", lo=0.0
    )
    vmin: tuple[float, float, float] = cf.numbers(
        (-5.0, -5.0, -5.0), "scheduling box low corner [m/s] (seed 0 Eq. 20)", length=3
    )
    vmax: tuple[float, float, float] = cf.numbers(
        (5.0, 5.0, 5.0), "scheduling box high corner [m/s]", length=3
    )
    validation: str = cf.text("hover", "name pattern of the validation bag")
    quadrotor: dict = cf.table(
        {},
        "QuadrotorParams overrides of the known elements (checked when they are built)",
        item=None,
    )

    @classmethod
    def from_dict(cls, d: dict | None, where: str = "identification") -> "IdentificationConfig":
        """The ``identification`` section (or the mapping itself) and its sections."""
        if isinstance(d, Mapping) and "identification" in d:
            d = d["identification"]
        d = d or {}
        kw = cf.parse_fields(cls, d, where, other_keys=_SECTIONS)
        for name, section in _SECTIONS.items():
            kw[name] = section.from_dict(d.get(name), cf.join(where, name))
        if "measurement_noise" in kw:
            kw["measurement_noise"] = _noise_pairs(
                kw["measurement_noise"], cf.join(where, "measurement_noise")
            )
        cfg = cls(**kw)
        if any(a >= b for a, b in zip(cfg.vmin, cfg.vmax)):
            raise cf.error(where, "vmin", f"{cfg.vmin} must be below vmax {cfg.vmax}")
        return cfg


#: nested sections -> their classes (each parsed by its from_dict)
_SECTIONS: dict[str, Any] = {
    "derivatives": deriv.DerivativeConfig,
    "uncertainty": unc.UncertaintyConfig,
    "covariance": ee.CovarianceConfig,
}


def _noise_pairs(noise: Mapping[str, tuple], where: str) -> dict:
    """``{channel: (std, rate_hz or None)}`` of the checked ``measurement_noise`` values."""
    out = {}
    for k, v in noise.items():
        if len(v) == 2 and not v[1] > 0:
            raise cf.error(where, f"{k}[1]", f"the rate must be > 0 Hz, got {v[1]!r}")
        out[k] = (v[0], v[1] if len(v) == 2 else None)
    return out


def parse_measurement_noise(v, where: str = "identification.measurement_noise") -> dict:
    """``measurement_noise`` (the declaration of :class:`IdentificationConfig`): state name
    (STATE_NAMES) or ``rotor`` -> white-noise std per sample, or ``[std, rate_hz]`` (the rate
    the channel was sampled at; default the grid rate) -> ``{channel: (std, rate or None)}``."""
    if v is None:
        return {}
    spec = cf.specs(IdentificationConfig)["measurement_noise"]
    return _noise_pairs(cf.check_value(spec, v, where), where)


def quadrotor_params(cfg: IdentificationConfig) -> QuadrotorParams:
    """The vehicle parameters of the known elements (``cfg.quadrotor`` overrides)."""
    return QuadrotorParams.from_dict(cfg.quadrotor) if cfg.quadrotor else QuadrotorParams()
