"""Configuration of a multisine signal set (frozen dataclasses with validating ``from_dict``).

YAML layout (``config/signals_phase2.yaml``)::

    duration: 100.0            # T, s: one period; harmonics of f0 = 1/T
    sample_rate: 50.0          # Hz; T * sample_rate must be an integer
    groups:                    # harmonics of each band shared out interleaved (seed 0 Sec. V)
      - name: reference
        channels: [u_d, v_d, w_d]
        band: [0.01, 0.5]      # Hz, closed; harmonics taken by an earlier group are skipped
        peak: 5.0              # per-channel peak |x| (scalar or one per channel), default 1
      - name: excitation
        channels: [ue_t, ue_a, ue_e, ue_r]
        band: [0.5, 5.0]       # -> (0.5, 5] since 0.5 Hz already belongs to "reference"
        energy: 1.0            # group energy sqrt(int_0^T u^T u dt) (Eq. 26) instead of peak
        power_fraction: [0.25, 0.25, 0.25, 0.25]   # share of the energy per channel
        spectrum: [[0.5, 1.0], [5.0, 1.0]]         # optional amplitude vs f breakpoints
    optimisation: {p_stages: [4, 16, 64, 256, 1024], max_iter: 150, clip_iter: 100}
    weights:                   # optional, seed 0 Eqs. (27)-(28)
      group: excitation        # the unit-energy group u_e (energy must be 1)
      excitation_magnitudes: [Delta_t, Delta_a, Delta_e, Delta_r]
      velocity_magnitudes: [Delta_u, Delta_v, Delta_w]

``spectrum`` may also be a mapping ``{channel: [[f, a], ...]}`` for per-channel spectra;
the amplitude of harmonic f is the piecewise-linear interpolation of the breakpoints
(flat when absent).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError
from lpv_sysid.signals.multisine.phase_opt import PhaseOptOptions

#: Limits checked before a table is allocated: one period of at most an hour (a flight is
#: minutes), at most 10 kHz (PX4 offboard streams run at <= 1 kHz), at most 2e6 samples per
#: channel (16 MB per channel; the phase optimiser holds a few such arrays per channel).
MAX_DURATION = 3600.0
MAX_SAMPLE_RATE = 10_000.0
MAX_SAMPLES = 2_000_000
#: Iteration counts of the phase optimiser (defaults 150, 100, 3): larger values never finish.

_BREAKPOINT = cf.FieldSpec(cf.NUMBERS, length=2, lo=0.0)
_POSITIVE = cf.FieldSpec(cf.NUMBER, lo=0.0, lo_open=True)
_POSITIVES = cf.FieldSpec(cf.NUMBERS, lo=0.0, lo_open=True)


def _breakpoints(v: Any, where: str) -> tuple[tuple[float, float], ...]:
    if not isinstance(v, (list, tuple)) or len(v) < 1:
        raise ConfigError(f"{where}: expected a list of [frequency, amplitude] pairs")
    pts = tuple(cf.check_value(_BREAKPOINT, p, f"{where}[{i}]") for i, p in enumerate(v))
    fs = [p[0] for p in pts]
    if any(b <= a for a, b in zip(fs, fs[1:])):
        raise ConfigError(f"{where}: breakpoint frequencies must increase strictly")
    if all(p[1] == 0 for p in pts):
        raise ConfigError(f"{where}: all amplitudes are zero")
    return pts


@dataclass(frozen=True)
class GroupConfig:
    """Channels that share one frequency band (interleaved harmonics)."""

    name: str = cf.text(doc="group name (weights.group refers to it)")
    channels: tuple[str, ...] = cf.texts(doc="channel names, unique", unique=True)
    band: tuple[float, float] = cf.numbers(doc="[low, high] Hz, low < high", length=2, lo=0.0)
    #: per channel peak |x| (a scalar applies to every channel); default 1
    peak: Optional[tuple[float, ...]] = None
    energy: Optional[float] = cf.number(
        None, "group energy sqrt(int u^T u dt), Eq. (26)", lo=0.0, lo_open=True
    )
    power_fraction: Optional[tuple[float, ...]] = cf.numbers(
        None, "share of the energy per channel (with energy)", lo=0.0, lo_open=True
    )
    spectra: Mapping[str, tuple[tuple[float, float], ...]] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "group") -> "GroupConfig":
        kw = cf.parse_fields(cls, d, where, other_keys=("peak", "spectrum"))
        ch, n = kw["channels"], len(kw["channels"])
        band = kw["band"]
        if not band[1] > band[0]:
            raise ConfigError(f"{where}.band: need low < high, got {list(band)}")
        if "peak" in d and "energy" in d:
            raise ConfigError(f"{where}: give either 'peak' or 'energy', not both")
        if "peak" in d:
            p = d["peak"]
            kw["peak"] = (
                (cf.check_value(_POSITIVE, p, f"{where}.peak"),) * n
                if not isinstance(p, (list, tuple))
                else cf.check_value(_POSITIVES, p, f"{where}.peak")
            )
            if len(kw["peak"]) != n:
                raise ConfigError(f"{where}.peak: expected {n} values, got {len(kw['peak'])}")
        pf = kw.get("power_fraction")
        if pf is not None:
            if kw.get("energy") is None:
                raise ConfigError(
                    f"{where}.power_fraction: only meaningful with 'energy' "
                    "(with 'peak' every channel is scaled to its own peak)"
                )
            if len(pf) != n:
                raise ConfigError(f"{where}.power_fraction: expected {n} values, got {len(pf)}")
            if abs(sum(pf) - 1.0) > 1e-9:
                raise ConfigError(f"{where}.power_fraction: must sum to 1, got {sum(pf)}")
        spectra: dict[str, tuple[tuple[float, float], ...]] = {}
        if "spectrum" in d:
            s = d["spectrum"]
            if isinstance(s, Mapping):
                for k, v in s.items():
                    if k not in ch:
                        raise ConfigError(f"{where}.spectrum: unknown channel {k!r}")
                    spectra[k] = _breakpoints(v, f"{where}.spectrum.{k}")
            else:
                bp = _breakpoints(s, f"{where}.spectrum")
                spectra = {c: bp for c in ch}
        return cls(spectra=spectra, **kw)


@dataclass(frozen=True)
class WeightsConfig:
    """Magnitudes for the weights R (Eq. 27) and Q (Eq. 28) of seed 0 Sec. V."""

    group: Optional[str] = cf.text(None, "the unit-energy group u_e", optional=True)
    excitation_magnitudes: Optional[tuple[float, ...]] = cf.numbers(
        None, "Delta_t, Delta_a, Delta_e, Delta_r (one per u_e channel)", lo=0.0, lo_open=True
    )
    velocity_magnitudes: Optional[tuple[float, ...]] = cf.numbers(
        None, "Delta_u, Delta_v, Delta_w", length=3, lo=0.0, lo_open=True
    )

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "weights") -> "WeightsConfig":
        kw = cf.parse_fields(cls, d, where)
        if kw.get("excitation_magnitudes") is not None and kw.get("group") is None:
            raise ConfigError(
                f"{where}.group: required with excitation_magnitudes (the u_e group)"
            )
        return cls(**kw)


@dataclass(frozen=True)
class SignalsConfig:
    """A full multisine design: period, rate, groups, optimiser options, weights."""

    duration: float = cf.number(
        doc="T, s: one period", lo=0.0, lo_open=True, hi=MAX_DURATION, unit=" s"
    )
    sample_rate: float = cf.number(
        doc="Hz; T * sample_rate an integer", lo=0.0, lo_open=True, hi=MAX_SAMPLE_RATE, unit=" Hz"
    )
    groups: tuple[GroupConfig, ...] = ()
    optimisation: PhaseOptOptions = PhaseOptOptions()
    weights: WeightsConfig = WeightsConfig()

    @property
    def n_samples(self) -> int:
        return int(round(self.duration * self.sample_rate))

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c for g in self.groups for c in g.channels)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "signals config") -> "SignalsConfig":
        kw = cf.parse_fields(
            cls,
            d,
            where,
            other_keys=("groups", "optimisation", "weights"),
            required=("duration", "sample_rate", "groups"),
        )
        T, fs = kw["duration"], kw["sample_rate"]
        # before anything is allocated: the table is duration * sample_rate rows per channel
        n = T * fs
        if n > MAX_SAMPLES:
            raise ConfigError(
                f"{where}: duration * sample_rate = {n:g} samples exceeds the limit of "
                f"{MAX_SAMPLES} samples per channel"
            )
        if abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 4:
            raise ConfigError(f"{where}: duration * sample_rate must be an integer >= 4, got {n}")
        gs = d["groups"]
        if not isinstance(gs, (list, tuple)) or not gs:
            raise ConfigError(f"{where}.groups: expected a non-empty list")
        groups = tuple(GroupConfig.from_dict(g, f"{where}.groups[{i}]") for i, g in enumerate(gs))
        names = [c for g in groups for c in g.channels]
        dup = sorted({c for c in names if names.count(c) > 1})
        if dup:
            raise ConfigError(f"{where}.groups: channel name(s) {dup} used more than once")
        gnames = [g.name for g in groups]
        if len(set(gnames)) != len(gnames):
            raise ConfigError(f"{where}.groups: duplicate group names {gnames}")
        for i, g in enumerate(groups):
            if g.band[1] >= fs / 2:
                raise ConfigError(
                    f"{where}.groups[{i}].band: upper edge {g.band[1]} Hz must be "
                    f"below the Nyquist frequency {fs / 2} Hz"
                )
        opts = PhaseOptOptions.from_dict(d.get("optimisation") or {}, f"{where}.optimisation")
        w = WeightsConfig.from_dict(d.get("weights") or {}, f"{where}.weights")
        if w.group is not None:
            match = [g for g in groups if g.name == w.group]
            if not match:
                raise ConfigError(f"{where}.weights.group: no group named {w.group!r} in {gnames}")
            g = match[0]
            if g.energy is None or abs(g.energy - 1.0) > 1e-12:
                raise ConfigError(
                    f"{where}.weights.group: group {w.group!r} must have energy: 1.0 "
                    "(unit-energy u_e, seed 0 Eq. 26) for R of Eq. (27)"
                )
            if w.excitation_magnitudes is not None and len(w.excitation_magnitudes) != len(
                g.channels
            ):
                raise ConfigError(
                    f"{where}.weights.excitation_magnitudes: {len(w.excitation_magnitudes)} "
                    f"values for {len(g.channels)} channels of group {w.group!r}"
                )
        return cls(T, fs, groups, opts, w)


def load_config(path: str) -> SignalsConfig:
    """Read a YAML file into :class:`SignalsConfig`; every problem is a ConfigError."""
    from lpv_sysid.io.files import read_yaml

    if not os.path.lexists(path):
        raise ConfigError(f"{path}: no such file")
    data = read_yaml(path)
    if data is None:
        raise ConfigError(f"{path}: empty file")
    return SignalsConfig.from_dict(data, where=path)


#: Phase-1 design of seed 0 Sec. IV (identical to config/signals_phase1.yaml; a test checks it):
#: 4-axis, 30 s multisine, uniform power spectral density in 0.2-2 Hz on u, v, w, yaw rate.
PHASE1_DEFAULT: dict[str, Any] = {
    "duration": 30.0,
    "sample_rate": 50.0,
    "groups": [
        {
            "name": "reference",
            "channels": ["u_ref", "v_ref", "w_ref", "r_ref"],
            "band": [0.2, 2.0],
            "peak": [1.0, 1.0, 0.5, 0.5],
        },
    ],
    "optimisation": {
        "p_stages": [4, 16, 64, 256, 1024],
        "max_iter": 150,
        "clip_iter": 100,
        "restarts": 3,
        "restart_max_harmonics": 40,
    },
}
