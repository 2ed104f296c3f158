"""The synthesis configuration file (config/synthesis.yaml), declared once.

Top-level sections: ``hinf`` (:class:`~lpv_sysid.synthesis.hinf.HinfOptions`), ``weights``
(:class:`WeightsSection`, seed 0 Eqs. 27-28), ``velocity_states`` (the states of
z = Q^-1 (v - v_d), Eq. 18), ``uncertainty``
(:class:`~lpv_sysid.synthesis.uncertainty_set.UncertaintySettings`, Eqs. 22-23), ``verify``
(:class:`VerifySection`), ``loop_delay`` (:class:`LoopDelaySection`) and ``feedforward``
(true | false | :class:`FeedforwardSection`).
Every key is declared with :mod:`lpv_sysid.configuration.fields`; a misspelt key anywhere is
refused naming the file, the section and the key.

>>> cfg = SynthesisConfig.from_dict({"verify": {"n_random": 5}}, "synthesis.yaml")
>>> cfg.verify.n_random, cfg.velocity_states, cfg.feedforward.enabled
(5, ('u', 'v', 'w'), True)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Optional

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError
from lpv_sysid.synthesis.feedforward import COND_MAX_DEFAULT, FeedforwardLayout
from lpv_sysid.synthesis.hinf import HinfOptions
from lpv_sysid.synthesis.uncertainty_set import UncertaintySettings
from lpv_sysid.synthesis.verify import VERIFY_SETTINGS


@dataclass(frozen=True)
class WeightsSection:
    """``weights``: R and Q of seed 0 Eqs. (27)-(28) from magnitudes and the horizon T, or
    ``summary``, a signals summary.yaml holding R and Q (``--summary`` overrides it)."""

    T: Optional[float] = cf.number(
        None,
        "duration of the phase-2 excitation (Eq. 26)",
        lo=0.0,
        lo_open=True,
        unit=" s",
        optional=True,
    )
    input_magnitudes: Optional[tuple] = cf.numbers(
        None, "Delta of each excitation channel (Eq. 32)", lo=0.0, lo_open=True, optional=True
    )
    output_magnitudes: Optional[tuple] = cf.numbers(
        None, "Delta_u, Delta_v, Delta_w in m/s (Eq. 32)", lo=0.0, lo_open=True, optional=True
    )
    summary: Optional[str] = cf.text(None, "a signals summary.yaml with R and Q", optional=True)

    @classmethod
    def from_dict(cls, d: Optional[Mapping[str, Any]], where: str = "weights") -> "WeightsSection":
        return cls(**cf.parse_fields(cls, d or {}, where))


@dataclass(frozen=True)
class VerifySection:
    """``verify``: the independent verification run right after the synthesis."""

    n_random: int = cf.count(
        VERIFY_SETTINGS["n_random"], "random interior scheduling points checked", hi=100_000
    )
    seed: int = cf.count(VERIFY_SETTINGS["seed"], "seed of those points")

    @classmethod
    def from_dict(cls, d: Optional[Mapping[str, Any]], where: str = "verify") -> "VerifySection":
        return cls(**cf.parse_fields(cls, d or {}, where))


@dataclass(frozen=True)
class LoopDelaySection:
    """``loop_delay``: the measured state -> command -> actuator latency plus margin that the
    certificate must cover (:mod:`lpv_sysid.synthesis.delay`); null: the proven margin."""

    bound_s: Optional[float] = cf.number(
        None,
        "constant loop delay the proof must cover",
        lo=0.0,
        hi=1.0,
        hi_open=True,
        unit=" s",
        optional=True,
    )

    @classmethod
    def from_dict(
        cls, d: Optional[Mapping[str, Any]], where: str = "loop_delay"
    ) -> "LoopDelaySection":
        return cls(**cf.parse_fields(cls, d or {}, where))


@dataclass(frozen=True)
class FeedforwardSection:
    """``feedforward`` (seed 2 Sec. 5.1): on/off, the conditioning limit of the per-vertex
    solve and the state layout (:class:`~lpv_sysid.synthesis.feedforward.FeedforwardLayout`).
    ``given``: the file says something (a bare ``true`` included); absent, the default is on
    for the quadrotor layout only."""

    enabled: bool = cf.flag(True, "write F_ff (and F_jerk) per vertex")
    cond_max: float = cf.number(
        COND_MAX_DEFAULT, "largest condition number of a vertex solve", lo=1.0
    )
    layout: FeedforwardLayout = field(default_factory=FeedforwardLayout)
    given: bool = False

    @classmethod
    def from_value(cls, v: Any, where: str = "feedforward") -> "FeedforwardSection":
        """``true`` | ``false`` | ``{enabled, cond_max, <layout keys>}``."""
        if isinstance(v, bool):
            return cls(enabled=v, given=True)
        if not isinstance(v, Mapping):
            raise ConfigError(f"{where}: expected true, false or a mapping, got {v!r}")
        layout_keys = [k for k in v if k not in ("enabled", "cond_max")]
        kw = cf.parse_fields(cls, v, where, other_keys=layout_keys)
        layout = FeedforwardLayout.from_dict({k: v[k] for k in layout_keys}, where)
        return cls(layout=layout, given=True, **kw)


@dataclass(frozen=True)
class SynthesisConfig:
    """config/synthesis.yaml (module docstring)."""

    velocity_states: tuple = cf.texts(
        ("u", "v", "w"), "states entering z = Q^-1 (v - v_d), Eq. (18)", unique=True
    )
    hinf: HinfOptions = field(default_factory=HinfOptions)
    weights: WeightsSection = field(default_factory=WeightsSection)
    uncertainty: UncertaintySettings = field(default_factory=UncertaintySettings)
    verify: VerifySection = field(default_factory=VerifySection)
    feedforward: FeedforwardSection = field(default_factory=FeedforwardSection)
    loop_delay: LoopDelaySection = field(default_factory=LoopDelaySection)

    @classmethod
    def from_dict(cls, d: Any, where: str = "synthesis") -> "SynthesisConfig":
        sections = ("hinf", "weights", "uncertainty", "verify", "loop_delay", "feedforward")
        kw: dict[str, Any] = cf.parse_fields(cls, d, where, other_keys=sections)
        for name in sections[:5]:
            if d.get(name) is not None and not isinstance(d[name], Mapping):
                raise cf.error(where, name, f"expected a mapping, got {type(d[name]).__name__}")
        kw["hinf"] = HinfOptions.from_dict(d.get("hinf"), cf.join(where, "hinf"))
        kw["weights"] = WeightsSection.from_dict(d.get("weights"), cf.join(where, "weights"))
        kw["uncertainty"] = UncertaintySettings.from_dict(
            d.get("uncertainty"), cf.join(where, "uncertainty")
        )
        kw["verify"] = VerifySection.from_dict(d.get("verify"), cf.join(where, "verify"))
        kw["loop_delay"] = LoopDelaySection.from_dict(
            d.get("loop_delay"), cf.join(where, "loop_delay")
        )
        if "feedforward" in d:
            kw["feedforward"] = FeedforwardSection.from_value(
                d["feedforward"], cf.join(where, "feedforward")
            )
        return cls(**kw)

    @classmethod
    def load(cls, path: str) -> "SynthesisConfig":
        from lpv_sysid.io.files import read_yaml_mapping

        return cls.from_dict(read_yaml_mapping(path), str(path))
