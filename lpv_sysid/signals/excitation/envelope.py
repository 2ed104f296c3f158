"""The design envelope of a phase-2 signal (``certificate.design`` of the gains).

:func:`design_envelope` turns a phase-2 signals summary into the design envelope the gains
record (``certificate.design``): the bounds of the *played* signal (table linearly
interpolated, raised-cosine fades of at least ``fade_s``) that the controller enforces, and
:func:`check_design` checks a signal table against it at load.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.signals.excitation.player import DEFAULT_RAMP_S, PHASE2_CHANNELS, PHASE2_EXCITATION
from lpv_sysid.signals.store import validate_table


def played_envelope(
    peak: Sequence[float], f_max: Sequence[float], fade_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rate and acceleration bounds ``(R1, R2)`` of a played reference channel: a signal with
    harmonics up to ``f_max`` Hz and peak ``P`` (Bernstein: ``|s'| <= 2 pi f P``,
    ``|s''| <= (2 pi f)^2 P``) multiplied by a raised-cosine fade of length ``r = fade_s``
    (``|e'| <= pi / (2 r)``, ``|e''| <= pi^2 / (2 r^2)``):
    ``R1 = 2 pi f P + pi P / (2 r)``,
    ``R2 = (2 pi f)^2 P + pi (2 pi f P) / r + pi^2 P / (2 r^2)``."""
    P = np.asarray(peak, dtype=float)
    w = 2.0 * math.pi * np.asarray(f_max, dtype=float)
    r = float(fade_s)
    if not (r > 0 and np.all(P > 0) and np.all(w > 0)):
        raise ConfigError(
            f"design envelope: need peaks, frequencies and fade > 0, got "
            f"{P.tolist()}, {(w / (2 * math.pi)).tolist()}, {r}"
        )
    R1 = w * P + math.pi * P / (2.0 * r)
    R2 = w * w * P + math.pi * w * P / r + math.pi**2 * P / (2.0 * r * r)
    return R1, R2


def envelope_dict(
    reference_peak: Sequence[float],
    reference_f_max: Sequence[float],
    knot_interval_s: float,
    excitation_peak: Sequence[float],
    fade_s: float = DEFAULT_RAMP_S,
    source: str = "",
) -> dict:
    """The ``certificate.design`` mapping (:class:`lpv_sysid.io.formats.DesignEnvelope`)."""
    R1, R2 = played_envelope(reference_peak, reference_f_max, fade_s)
    return {
        "reference_peak": [float(x) for x in reference_peak],
        "reference_rate": R1.tolist(),
        "reference_accel": R2.tolist(),
        "knot_interval_s": float(knot_interval_s),
        "fade_s": float(fade_s),
        "excitation_peak": [float(x) for x in excitation_peak],
        "source": source,
    }


def design_envelope(
    summary: dict, fade_s: float = DEFAULT_RAMP_S, source: str = "signals summary"
) -> dict:
    """``certificate.design`` from a phase-2 signals summary (``lpv-sysid signals``,
    :func:`lpv_sysid.signals.store.summary`): per reference channel (``u_d, v_d, w_d``) its
    peak and highest harmonic (``frequency_range_hz``), per excitation channel
    (``ue_t, ue_a, ue_e, ue_r``) its peak, the table's sample interval. ConfigError when the
    summary is not of a phase-2 signal."""
    try:
        chans = {c["name"]: c for c in summary["channels"]}
        missing = [n for n in PHASE2_CHANNELS + PHASE2_EXCITATION if n not in chans]
        if missing:
            raise ConfigError(f"{source}: not a phase-2 signal (channels {missing} missing)")
        ref = [chans[n] for n in PHASE2_CHANNELS]
        return envelope_dict(
            [float(c["peak"]) for c in ref],
            [float(c["frequency_range_hz"][1]) for c in ref],
            1.0 / float(summary["sample_rate"]),
            [float(chans[n]["peak"]) for n in PHASE2_EXCITATION],
            fade_s,
            source,
        )
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ConfigError(
            f"{source}: cannot read the phase-2 channels ({type(exc).__name__}: {exc})"
        ) from None


def check_design(t, u, names, design, ramp: float, where: str = "signals") -> None:
    """A phase-2 table against the design envelope of the gains (``design``: a
    :class:`lpv_sysid.io.formats.DesignEnvelope`): reference peaks, the table's own rates
    (chord slopes, which the interpolated playback reproduces) and accelerations (second
    divided differences), excitation peaks, the table interval and the fade ``ramp``;
    ConfigError naming the first violation."""
    t, u, names = validate_table(t, u, names, where=where)
    missing = [n for n in PHASE2_CHANNELS + PHASE2_EXCITATION if n not in names]
    if missing:
        raise ConfigError(f"{where}: channel(s) {missing} missing for phase 2")
    dt = float(t[1] - t[0])
    tol = 1e-9
    if ramp < design.fade_s * (1 - tol):
        raise ConfigError(
            f"{where}: ramp_s {ramp:g} s is shorter than the fade the gains were "
            f"designed for ({design.fade_s:g} s): the fades would exceed the "
            "designed reference rates"
        )
    if dt > design.knot_interval_s * (1 + tol):
        raise ConfigError(
            f"{where}: sample interval {dt:g} s is coarser than the design's "
            f"{design.knot_interval_s:g} s"
        )
    for k, n in enumerate(PHASE2_CHANNELS):
        x = u[:, names.index(n)]
        peak, rate = float(np.max(np.abs(x))), float(np.max(np.abs(np.diff(x)))) / dt
        if peak > design.reference_peak[k] * (1 + tol):
            raise ConfigError(
                f"{where}: {n} peak {peak:.4g} m/s exceeds the design peak "
                f"{design.reference_peak[k]:.4g} m/s the gains were designed for"
            )
        if rate > design.reference_rate[k] * (1 + tol):
            raise ConfigError(
                f"{where}: {n} changes at {rate:.4g} m/s^2, beyond the design rate "
                f"{design.reference_rate[k]:.4g} m/s^2"
            )
        # second divided difference = x''(xi) of the sampled signal: the gains' gamma bounds
        # u_e -> z only; the reference-driven part is covered for references within the
        # recorded rate AND acceleration bounds (docs/certificate.md section 3b)
        accel = float(np.max(np.abs(np.diff(x, 2)))) / dt**2 if x.size > 2 else 0.0
        if accel > design.reference_accel[k] * (1 + tol):
            raise ConfigError(
                f"{where}: {n} accelerates at {accel:.4g} m/s^3, beyond the design "
                f"acceleration {design.reference_accel[k]:.4g} m/s^3 the gains were designed "
                "for (refused before flight: the certified bound does not cover the "
                "reference-driven terms of a faster reference)"
            )
    for k, n in enumerate(PHASE2_EXCITATION):
        peak = float(np.max(np.abs(u[:, names.index(n)])))
        if peak > design.excitation_peak[k] * (1 + tol):
            raise ConfigError(
                f"{where}: {n} peak {peak:.4g} exceeds the design excitation peak "
                f"{design.excitation_peak[k]:.4g} (the gains' R is designed for "
                "that signal)"
            )
