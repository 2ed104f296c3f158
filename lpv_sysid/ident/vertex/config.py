"""``config/identification.yaml``: the configuration of the vertex identification
(:mod:`lpv_sysid.ident.vertex`, seed 0 Sec. IV) and the vehicle parameters it names."""

from __future__ import annotations

from dataclasses import dataclass, field

from lpv_sysid.configuration.fields import check_keys, is_count, is_finite_number
from lpv_sysid.errors import ConfigError
from lpv_sysid.ident import derivatives as deriv
from lpv_sysid.ident import equation_error as ee
from lpv_sysid.ident.vertex import uncertainty as unc
from lpv_sysid.models.quadrotor import STATE_NAMES, QuadrotorParams


@dataclass(frozen=True)
class IdentificationConfig:
    """``config/identification.yaml`` (all sections optional)."""

    derivatives: deriv.DerivativeConfig = field(default_factory=deriv.DerivativeConfig)
    uncertainty: unc.UncertaintyConfig = field(default_factory=unc.UncertaintyConfig)
    trim_duration: float = 10.0  # s of steady reference before the excitation (seed 0 Sec. IV)
    trim_average: float = 5.0  # s at the end of the trim segment averaged for x0, u0
    edge: float = 0.5  # s dropped at both ends of the fit segment (smoother end effects)
    min_fit_duration: float = 5.0  # s, shorter excitation segments are refused
    sample_rate: float = 100.0  # Hz, common grid of dataprep
    max_lag: int | None = None  # residual autocorrelation lags (covariance.method residual_acf)
    intercept: bool = True  # per-row bias term (Klein & Morelli), see equation_error
    model: str = "taylor2"  # "taylor2" (ident.taylor) or "appendix_b" (plain seed 0 App. B)
    covariance: ee.CovarianceConfig = field(default_factory=ee.CovarianceConfig)
    equilibrium: bool = True  # taylor2: re-expand about the identified equilibrium (Eq. 13)
    motor: str = "identify"  # a_Omega, b_Omega: "identify" (motor rows, Eq. 8) or "known"
    motor_max_pinned: float = 0.01  # identify a_Omega, b_Omega only if no rotor is pinned at a
    # speed limit longer than this fraction of the fit segment
    motor_std: tuple[float, float] | None = None  # std of a_Omega, b_Omega where not identifiable
    instruments: bool = False  # taylor2: rotor speeds instrumented by the motor model (EIV check)
    motor_instrument: bool = True  # motor rows: measured speeds instrumented by the model's (EIV)
    measurement_noise: dict = field(
        default_factory=dict
    )  # EIV: {state or "rotor": std | [std, rate_hz]}
    excitation_threshold: float = 1e-6  # |u_e| above which the excitation counts as on
    vmin: tuple[float, float, float] = (-5.0, -5.0, -5.0)
    vmax: tuple[float, float, float] = (5.0, 5.0, 5.0)
    validation: str = "hover"  # name pattern of the validation bag
    quadrotor: dict = field(default_factory=dict)  # QuadrotorParams overrides (known elements)

    @classmethod
    def from_dict(cls, d: dict | None) -> "IdentificationConfig":
        if d is None:
            d = {}
        if not isinstance(d, dict):
            raise ConfigError(f"identification config must be a mapping, got {type(d).__name__}")
        from lpv_sysid.signals.multisine import MAX_SAMPLE_RATE

        d = d.get("identification", d)
        if not isinstance(d, dict):
            raise ConfigError(f"identification: expected a mapping, got {type(d).__name__}")
        d = dict(d)
        check_keys(d, cls.__dataclass_fields__, "identification", list_allowed=True)
        kw: dict = {}
        kw["derivatives"] = deriv.DerivativeConfig.from_dict(d.pop("derivatives", None))
        kw["uncertainty"] = unc.UncertaintyConfig.from_dict(d.pop("uncertainty", None))
        kw["covariance"] = ee.CovarianceConfig.from_dict(d.pop("covariance", None))
        for key in (
            "trim_duration",
            "trim_average",
            "edge",
            "min_fit_duration",
            "sample_rate",
            "excitation_threshold",
            "motor_max_pinned",
        ):
            if key in d:
                v = d.pop(key)
                if not is_finite_number(v) or v < 0:
                    raise ConfigError(
                        f"identification.{key} must be a finite number >= 0, got {v!r}"
                    )
                if (
                    key == "sample_rate" and v > MAX_SAMPLE_RATE
                ):  # the common grid is allocated from it
                    raise ConfigError(
                        f"identification.sample_rate: {v:g} Hz exceeds the limit of "
                        f"{MAX_SAMPLE_RATE:g} Hz"
                    )
                kw[key] = float(v)
        if "max_lag" in d:
            v = d.pop("max_lag")
            if v is not None and not is_count(v):
                raise ConfigError(
                    f"identification.max_lag must be null or an integer >= 0, got {v!r}"
                )
            kw["max_lag"] = v
        for key in ("vmin", "vmax"):
            if key in d:
                v = d.pop(key)
                if not isinstance(v, (list, tuple)) or len(v) != 3:
                    raise ConfigError(
                        f"identification.{key} must be a list of 3 numbers, got {v!r}"
                    )
                kw[key] = tuple(float(a) for a in v)
        for key in ("intercept", "equilibrium", "instruments", "motor_instrument"):
            if key in d:
                v = d.pop(key)
                if not isinstance(v, bool):
                    raise ConfigError(f"identification.{key} must be true or false, got {v!r}")
                kw[key] = v
        if "measurement_noise" in d:
            kw["measurement_noise"] = parse_measurement_noise(d.pop("measurement_noise"))
        if "motor_std" in d:
            v = d.pop("motor_std")
            if v is not None and (
                not isinstance(v, (list, tuple))
                or len(v) != 2
                or not all(is_finite_number(a) and a > 0 for a in v)
            ):
                raise ConfigError(
                    f"identification.motor_std must be null or [std a_Omega, std b_Omega] > 0, "
                    f"got {v!r}"
                )
            kw["motor_std"] = None if v is None else (float(v[0]), float(v[1]))
        if "motor" in d:
            v = d.pop("motor")
            if v not in ("identify", "known"):
                raise ConfigError(f"identification.motor must be 'identify' or 'known', got {v!r}")
            kw["motor"] = v
        if "model" in d:
            v = d.pop("model")
            if v not in ("taylor2", "appendix_b"):
                raise ConfigError(
                    f"identification.model must be 'taylor2' or 'appendix_b', got {v!r}"
                )
            kw["model"] = v
        if "validation" in d:
            kw["validation"] = str(d.pop("validation"))
        if "quadrotor" in d:
            q = d.pop("quadrotor")
            if not isinstance(q, dict):
                raise ConfigError("identification.quadrotor must be a mapping")
            kw["quadrotor"] = q
        cfg = cls(**kw)
        if cfg.sample_rate <= 0:
            raise ConfigError("identification.sample_rate must be > 0")
        if any(a >= b for a, b in zip(cfg.vmin, cfg.vmax)):
            raise ConfigError(f"identification.vmin {cfg.vmin} must be below vmax {cfg.vmax}")
        return cfg


def parse_measurement_noise(v) -> dict:
    """``measurement_noise``: state name (STATE_NAMES) or ``rotor`` -> white-noise std per sample,
    or ``[std, rate_hz]`` (the rate the channel was sampled at; default the grid rate)."""
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise ConfigError(
            f"identification.measurement_noise must be a mapping, got {type(v).__name__}"
        )
    out = {}
    for k, x in v.items():
        if k not in STATE_NAMES and k != "rotor":
            raise ConfigError(
                f"identification.measurement_noise: unknown channel {k!r}; "
                f"allowed: {list(STATE_NAMES) + ['rotor']}"
            )
        pair = list(x) if isinstance(x, (list, tuple)) else [x, None]
        if (
            len(pair) != 2
            or not is_finite_number(pair[0])
            or pair[0] < 0
            or (pair[1] is not None and (not is_finite_number(pair[1]) or pair[1] <= 0))
        ):
            raise ConfigError(
                f"identification.measurement_noise.{k} must be std >= 0 or [std, rate_hz > 0], "
                f"got {x!r}"
            )
        out[k] = (float(pair[0]), None if pair[1] is None else float(pair[1]))
    return out


def quadrotor_params(cfg: IdentificationConfig) -> QuadrotorParams:
    """The vehicle parameters of the known elements (``cfg.quadrotor`` overrides)."""
    return QuadrotorParams.from_dict(cfg.quadrotor) if cfg.quadrotor else QuadrotorParams()
