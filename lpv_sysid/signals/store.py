"""Signal files: ``signals.npz`` (``t`` (N,), ``u`` (N, n), ``names`` (n,)) and ``summary.yaml``
(docs/ARCHITECTURE.md section 5)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.signals import metrics
from lpv_sysid.signals.multisine import MAX_SAMPLE_RATE, SignalSet


def save_npz(path: str, t: np.ndarray, u: np.ndarray, names) -> None:
    """Write ``t``, ``u``, ``names`` (unicode array) to ``path`` (numpy .npz, uncompressed)."""
    from lpv_sysid.io.files import check_output

    check_output(path)  # an existing FIFO or device is refused, not opened
    try:
        with open(path, "wb") as fh:
            np.savez(
                fh,
                t=np.asarray(t, float),
                u=np.asarray(u, float),
                names=np.asarray(list(names), dtype=str),
            )
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write ({exc.strerror})") from None


def load_npz(path: str) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """Read and validate a signal file: ``t`` strictly increasing and uniform, ``u`` (N, n)
    finite, ``names`` n unique strings."""
    from lpv_sysid.io.files import read_npz

    if not os.path.lexists(path):
        raise ConfigError(f"{path}: no such file")
    z = read_npz(path)  # regular file, size cap, no pickles, complex arrays refused
    missing = [k for k in ("t", "u", "names") if k not in z]
    if missing:
        raise ConfigError(f"{path}: missing array(s) {missing}")
    return validate_table(z["t"], z["u"], z["names"], where=path)


def validate_table(
    t, u, names, where: str = "signals"
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    for key, a in (("t", t), ("u", u)):
        kind = np.asarray(a).dtype.kind
        if kind == "c":  # a cast to float would silently drop the imaginary part
            raise ConfigError(
                f"{where}: '{key}' is complex-valued; a real-valued signal is required"
            )
        if kind not in "fiu":
            raise ConfigError(f"{where}: '{key}' must be numeric, got dtype {np.asarray(a).dtype}")
    t = np.asarray(t, dtype=float)
    u = np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None]
    names = tuple(str(n) for n in np.atleast_1d(np.asarray(names)))
    if t.ndim != 1 or t.size < 2:
        raise ConfigError(f"{where}: 't' must be 1-D with >= 2 samples, got shape {t.shape}")
    if u.ndim != 2 or u.shape[0] != t.size:
        raise ConfigError(f"{where}: 'u' must be ({t.size}, n), got shape {u.shape}")
    if len(names) != u.shape[1] or len(set(names)) != len(names):
        raise ConfigError(f"{where}: 'names' must be {u.shape[1]} unique names, got {list(names)}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
        raise ConfigError(f"{where}: 't' or 'u' contains NaN or inf")
    d = np.diff(t)
    if np.any(d <= 0) or np.max(np.abs(d - d.mean())) > 1e-6 * d.mean():
        raise ConfigError(f"{where}: 't' must be a strictly increasing uniform grid")
    if d.mean() < 1.0 / MAX_SAMPLE_RATE * (1 - 1e-9):
        # before anything is sampled on this step: a 2e-9 s interval made a phase-2
        # simulation allocate a grid of ~1e9 samples (14 GB in 60 s)
        raise ConfigError(
            f"{where}: sample interval {d.mean():.3g} s is below {1.0 / MAX_SAMPLE_RATE:g} s "
            f"(sample rates above {MAX_SAMPLE_RATE:g} Hz are refused, as in the signal design)"
        )
    check_magnitude(t, u, names, where)
    return t, u, names


def check_magnitude(t: np.ndarray, u: np.ndarray, names, where: str = "signals") -> None:
    """A channel's energy ``dt sum u^2`` (seed 0 Eq. 26) and its sample-to-sample rate must
    be finite numbers: a table whose energy or rate overflows (amplitudes of ~1e154 and
    beyond, e.g. 1e308) is corrupt or mis-scaled, not a signal. (What the gains accept is
    checked against their design envelope: signals.excitation.check_design, and at run time
    by the controller.)"""
    dt = float(t[-1] - t[0]) / (t.size - 1)
    with np.errstate(over="ignore", invalid="ignore"):
        energy = dt * np.sum(u * u, axis=0)
        rate = np.max(np.abs(np.diff(u, axis=0)), axis=0) / dt
    bad = [
        str(names[j])
        for j in range(u.shape[1])
        if not (np.isfinite(energy[j]) and np.isfinite(rate[j]))
    ]
    if bad:
        raise ConfigError(
            f"{where}: channel(s) {bad} too large (max |u| "
            f"{float(np.max(np.abs(u))):.3g}): energy or rate overflows"
        )


def summary(sig: SignalSet) -> dict[str, Any]:
    """Plain-data summary: per channel band, harmonics, RPF (optimised and Schroeder-only),
    peak, rms, start/end values, harmonic leakage; the correlation matrix; R, Q."""
    content = metrics.harmonic_content(sig.u, sig.harmonics)
    corr = metrics.correlation_matrix(sig.u)
    chans = []
    for j, name in enumerate(sig.names):
        x = sig.u[:, j]
        chans.append(
            {
                "name": name,
                "group": sig.groups[j],
                "band_hz": [float(b) for b in sig.bands[j]],
                "harmonics": [int(h) for h in sig.harmonics[j]],
                "n_harmonics": int(sig.harmonics[j].size),
                "frequency_range_hz": [
                    float(sig.harmonics[j].min() * sig.f0),
                    float(sig.harmonics[j].max() * sig.f0),
                ],
                "rpf": float(sig.rpf[j]),
                "rpf_schroeder": float(sig.rpf_schroeder[j]),
                "peak": float(np.max(np.abs(x))),
                "rms": float(metrics.rms(x)),
                "start_value": float(x[0]),
                "end_value": float(x[-1]),
                "leakage_fraction": float(content[j].leakage_fraction),
            }
        )
    off = corr - np.diag(np.diag(corr))
    out: dict[str, Any] = {
        "format": "lpv_sysid/signals_summary@1",
        "duration": float(sig.duration),
        "sample_rate": float(sig.sample_rate),
        "n_samples": int(sig.t.size),
        "f0_hz": float(sig.f0),
        "channels": chans,
        "correlation": {
            "names": list(sig.names),
            "matrix": corr.tolist(),
            "max_abs_offdiagonal": float(np.max(np.abs(off))) if corr.shape[0] > 1 else 0.0,
        },
    }
    if sig.R is not None:
        out["R"] = sig.R.tolist()
    if sig.Q is not None:
        out["Q"] = sig.Q.tolist()
    return out


def save_summary(path: str, data: dict[str, Any]) -> None:
    import yaml

    from lpv_sysid.io.files import check_output

    check_output(path)
    try:
        with open(path, "w", encoding="utf-8") as fh:
            yaml.safe_dump(data, fh, sort_keys=False, default_flow_style=None, width=120)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write ({exc.strerror})") from None


def write_signal_set(out_dir: str, sig: SignalSet, force: bool = False) -> tuple[str, str]:
    """Write ``signals.npz`` and ``summary.yaml`` into ``out_dir`` (created); returns paths.
    An existing signal set there is not replaced unless ``force``: gains designed for it
    (``certificate.design``) and the excitation node would silently fly another signal."""
    from lpv_sysid.io.files import refuse_existing

    npz = os.path.join(out_dir, "signals.npz")
    yml = os.path.join(out_dir, "summary.yaml")
    refuse_existing(
        (npz, yml), force, " (a certificate's design envelope may refer to this signal set)"
    )
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{out_dir}: cannot create directory ({exc.strerror})") from None
    save_npz(npz, sig.t, sig.u, sig.names)
    save_summary(yml, summary(sig))
    return npz, yml
