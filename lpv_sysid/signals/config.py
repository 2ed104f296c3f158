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

import math
import os
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional

from lpv_sysid.errors import ConfigError
from lpv_sysid.signals.phase_opt import PhaseOptOptions
from lpv_sysid.validation import check_keys, is_count


#: Limits checked before a table is allocated: one period of at most an hour (a flight is
#: minutes), at most 10 kHz (PX4 offboard streams run at <= 1 kHz), at most 2e6 samples per
#: channel (16 MB per channel; the phase optimiser holds a few such arrays per channel).
MAX_DURATION = 3600.0
MAX_SAMPLE_RATE = 10_000.0
MAX_SAMPLES = 2_000_000
#: Iteration counts of the phase optimiser (defaults 150, 100, 3): larger values never finish.
MAX_COUNTS = {"max_iter": 100_000, "clip_iter": 100_000, "restarts": 1_000}


def _num(v: Any, where: str, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ConfigError(f"{where}: expected a number, got {v!r}")
    x = float(v)
    if not math.isfinite(x):
        raise ConfigError(f"{where}: must be finite, got {v!r}")
    if positive and x <= 0:
        raise ConfigError(f"{where}: must be > 0, got {v!r}")
    if nonneg and x < 0:
        raise ConfigError(f"{where}: must be >= 0, got {v!r}")
    return x


def _int(v: Any, where: str, *, minimum: int = 0) -> int:
    if not is_count(v, minimum):
        raise ConfigError(f"{where}: expected an integer >= {minimum}, got {v!r}")
    return int(v)


def _num_list(v: Any, where: str, n: Optional[int] = None, **kw) -> tuple[float, ...]:
    if not isinstance(v, (list, tuple)):
        raise ConfigError(f"{where}: expected a list, got {v!r}")
    if n is not None and len(v) != n:
        raise ConfigError(f"{where}: expected {n} values, got {len(v)}")
    return tuple(_num(x, f"{where}[{i}]", **kw) for i, x in enumerate(v))


def _breakpoints(v: Any, where: str) -> tuple[tuple[float, float], ...]:
    if not isinstance(v, (list, tuple)) or len(v) < 1:
        raise ConfigError(f"{where}: expected a list of [frequency, amplitude] pairs")
    pts = tuple(tuple(_num_list(p, f"{where}[{i}]", 2, nonneg=True)) for i, p in enumerate(v))
    fs = [p[0] for p in pts]
    if any(b <= a for a, b in zip(fs, fs[1:])):
        raise ConfigError(f"{where}: breakpoint frequencies must increase strictly")
    if all(p[1] == 0 for p in pts):
        raise ConfigError(f"{where}: all amplitudes are zero")
    return pts  # type: ignore[return-value]


@dataclass(frozen=True)
class GroupConfig:
    """Channels that share one frequency band (interleaved harmonics)."""

    name: str
    channels: tuple[str, ...]
    band: tuple[float, float]
    peak: Optional[tuple[float, ...]] = None  # per channel peak |x|; default 1
    energy: Optional[float] = None  # group energy, Eq. (26)
    power_fraction: Optional[tuple[float, ...]] = None  # with ``energy`` only
    spectra: Mapping[str, tuple[tuple[float, float], ...]] = field(default_factory=dict)

    KEYS = frozenset({"name", "channels", "band", "peak", "energy", "power_fraction", "spectrum"})

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "group") -> "GroupConfig":
        check_keys(d, cls.KEYS, where, required={"name", "channels", "band"}, list_allowed=True)
        name = d["name"]
        if not isinstance(name, str) or not name:
            raise ConfigError(f"{where}.name: expected a non-empty string, got {name!r}")
        ch = d["channels"]
        if (
            not isinstance(ch, (list, tuple))
            or not ch
            or not all(isinstance(c, str) and c for c in ch)
        ):
            raise ConfigError(f"{where}.channels: expected a non-empty list of names, got {ch!r}")
        if len(set(ch)) != len(ch):
            raise ConfigError(f"{where}.channels: duplicate names in {list(ch)}")
        n = len(ch)
        band = _num_list(d["band"], f"{where}.band", 2, nonneg=True)
        if not band[1] > band[0]:
            raise ConfigError(f"{where}.band: need low < high, got {list(band)}")
        peak = energy = pf = None
        if "peak" in d and "energy" in d:
            raise ConfigError(f"{where}: give either 'peak' or 'energy', not both")
        if "peak" in d:
            p = d["peak"]
            peak = (
                (_num(p, f"{where}.peak", positive=True),) * n
                if not isinstance(p, (list, tuple))
                else _num_list(p, f"{where}.peak", n, positive=True)
            )
        if "energy" in d:
            energy = _num(d["energy"], f"{where}.energy", positive=True)
        if "power_fraction" in d:
            if energy is None:
                raise ConfigError(
                    f"{where}.power_fraction: only meaningful with 'energy' "
                    "(with 'peak' every channel is scaled to its own peak)"
                )
            pf = _num_list(d["power_fraction"], f"{where}.power_fraction", n, positive=True)
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
        return cls(name, tuple(ch), band, peak, energy, pf, spectra)  # type: ignore[arg-type]


@dataclass(frozen=True)
class WeightsConfig:
    """Magnitudes for the weights R (Eq. 27) and Q (Eq. 28) of seed 0 Sec. V."""

    group: Optional[str] = None
    excitation_magnitudes: Optional[tuple[float, ...]] = None  # Delta_t, Delta_a, Delta_e, Delta_r
    velocity_magnitudes: Optional[tuple[float, ...]] = None  # Delta_u, Delta_v, Delta_w

    KEYS = frozenset({"group", "excitation_magnitudes", "velocity_magnitudes"})

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "weights") -> "WeightsConfig":
        check_keys(d, cls.KEYS, where, list_allowed=True)
        g = d.get("group")
        if g is not None and not isinstance(g, str):
            raise ConfigError(f"{where}.group: expected a group name, got {g!r}")
        ex = vel = None
        if "excitation_magnitudes" in d:
            if g is None:
                raise ConfigError(
                    f"{where}.group: required with excitation_magnitudes (the u_e group)"
                )
            ex = _num_list(
                d["excitation_magnitudes"], f"{where}.excitation_magnitudes", positive=True
            )
        if "velocity_magnitudes" in d:
            vel = _num_list(
                d["velocity_magnitudes"], f"{where}.velocity_magnitudes", 3, positive=True
            )
        return cls(g, ex, vel)


def _options_from_dict(d: Mapping[str, Any], where: str = "optimisation") -> PhaseOptOptions:
    keys = {
        "p_stages",
        "max_iter",
        "clip_iter",
        "clip_level",
        "restarts",
        "restart_max_harmonics",
        "seed",
    }
    check_keys(d, keys, where, list_allowed=True)
    kw: dict[str, Any] = {}
    if "p_stages" in d:
        kw["p_stages"] = _num_list(d["p_stages"], f"{where}.p_stages", positive=True)
    for k in ("max_iter", "clip_iter", "restarts", "restart_max_harmonics", "seed"):
        if k in d:
            kw[k] = _int(d[k], f"{where}.{k}")
            if k in MAX_COUNTS and kw[k] > MAX_COUNTS[k]:  # a count of 10**18 never finishes
                raise ConfigError(f"{where}.{k}: {kw[k]} exceeds the limit of {MAX_COUNTS[k]}")
    if "clip_level" in d:
        kw["clip_level"] = _num(d["clip_level"], f"{where}.clip_level", positive=True)
    return PhaseOptOptions(**kw)


@dataclass(frozen=True)
class SignalsConfig:
    """A full multisine design: period, rate, groups, optimiser options, weights."""

    duration: float
    sample_rate: float
    groups: tuple[GroupConfig, ...]
    optimisation: PhaseOptOptions = PhaseOptOptions()
    weights: WeightsConfig = WeightsConfig()

    KEYS = frozenset({"duration", "sample_rate", "groups", "optimisation", "weights"})

    @property
    def n_samples(self) -> int:
        return int(round(self.duration * self.sample_rate))

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c for g in self.groups for c in g.channels)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "signals config") -> "SignalsConfig":
        check_keys(
            d, cls.KEYS, where, required={"duration", "sample_rate", "groups"}, list_allowed=True
        )
        T = _num(d["duration"], f"{where}.duration", positive=True)
        fs = _num(d["sample_rate"], f"{where}.sample_rate", positive=True)
        # before anything is allocated: the table is duration * sample_rate rows per channel
        if T > MAX_DURATION:
            raise ConfigError(f"{where}.duration: {T:g} s exceeds the limit of {MAX_DURATION:g} s")
        if fs > MAX_SAMPLE_RATE:
            raise ConfigError(
                f"{where}.sample_rate: {fs:g} Hz exceeds the limit of {MAX_SAMPLE_RATE:g} Hz"
            )
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
        opts = _options_from_dict(d.get("optimisation") or {}, f"{where}.optimisation")
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
    from lpv_sysid.io.yaml_file import read_yaml

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
