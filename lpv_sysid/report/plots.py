"""Report figures (matplotlib, Agg backend; no data loading here).

Each function takes arrays and an output path, writes one PNG and returns the path.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Optional, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lpv_sysid.ident.nonlinear import AXIS_TITLES, RegressorCorrelation  # noqa: E402
from lpv_sysid.report.margins import RunMargins  # noqa: E402

VEL_LABELS = ("u [m/s]", "v [m/s]", "w [m/s]")


def _save(fig: Any, path: Path, layout: bool = True) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if layout:
        fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_tracking(
    t: np.ndarray,
    v_d: np.ndarray,
    v: np.ndarray,
    path: Path,
    title: str = "",
    box: Optional[tuple[Sequence[float], Sequence[float]]] = None,
) -> Path:
    """Body velocity (solid) and reference (black dashed), like seed 0 Fig. 8; ``box``
    ``(min, max)``: the scheduling box edges (dotted)."""
    fig, axes = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
    for i, ax in enumerate(axes):
        ax.plot(t, v[:, i], lw=1.0, label="v")
        ax.plot(t, v_d[:, i], "k--", lw=1.0, label="v_d")
        if box is not None:
            for edge in (box[0][i], box[1][i]):
                ax.axhline(float(edge), color="0.4", ls=":", lw=0.8)
        ax.set_ylabel(VEL_LABELS[i])
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t [s]")
    if title:
        axes[0].set_title(title)
    return _save(fig, path)


def plot_perturbation(
    t: np.ndarray,
    err: np.ndarray,
    path: Path,
    title: str = "",
    bounds: Optional[Sequence[float]] = None,
) -> Path:
    """Velocity perturbation v - v_d, like seed 0 Fig. 9 (optional +-Delta lines of Eq. 32)."""
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for i, name in enumerate(("u - u_d", "v - v_d", "w - w_d")):
        ax.plot(t, err[:, i], lw=1.0, label=name)
    if bounds is not None:
        for b in bounds:
            ax.axhline(b, color="0.5", ls=":", lw=0.8)
            ax.axhline(-b, color="0.5", ls=":", lw=0.8)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("[m/s]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=3)
    if title:
        ax.set_title(title)
    return _save(fig, path)


#: |r| at or above which two regressors are called near-collinear (report text and plots)
COLLINEAR = 0.95


def _heatmap(
    ax: Any, names: Sequence[str], C: np.ndarray, title: str, mark: float = COLLINEAR
) -> Any:
    """Signed correlation on a diverging map fixed to [-1, 1]; cells with |r| >= ``mark`` off the
    diagonal are outlined in black and their value printed bold."""
    M = np.ma.masked_invalid(C)
    im = ax.imshow(M, vmin=-1.0, vmax=1.0, cmap="RdBu_r")
    n = len(names)
    ax.set_xticks(range(n))
    ax.set_yticks(range(n))
    fs = 7 if n <= 7 else 6
    ax.set_xticklabels(names, rotation=40, ha="right", fontsize=fs)
    ax.set_yticklabels(names, fontsize=fs)
    for i in range(n):
        for j in range(n):
            val = C[i, j]
            hot = i != j and np.isfinite(val) and abs(val) >= mark
            ax.text(
                j,
                i,
                "-" if not np.isfinite(val) else f"{val:+.2f}",
                ha="center",
                va="center",
                fontsize=fs,
                fontweight="bold" if hot else "normal",
                color="w" if np.isfinite(val) and abs(val) > 0.6 else "k",
            )
            if hot:
                ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="k", lw=1.6))
    ax.set_title(title, fontsize=9)
    return im


def plot_regressor_correlations(
    corrs: Sequence[RegressorCorrelation], path: Path, title: str = ""
) -> Path:
    """Signed correlation coefficients of the Eq. (6) regressors per axis (seed 0 Fig. 10), one
    colour bar for all panels; near-collinear pairs (|r| >= :data:`COLLINEAR`) outlined."""
    fig, axes = plt.subplots(2, 3, figsize=(14, 9.5))
    im = None
    for ax, rc in zip(axes.ravel(), corrs):
        im = _heatmap(ax, rc.names, rc.corr, AXIS_TITLES.get(rc.axis, rc.axis))
    for ax in axes.ravel()[len(corrs) :]:
        ax.axis("off")
    fig.suptitle(
        (title + "\n" if title else "") + f"outlined: near-collinear pairs, |r| >= {COLLINEAR:g}",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0, 0.92, 1))
    if im is not None:
        cax = fig.add_axes((0.935, 0.15, 0.015, 0.7))
        fig.colorbar(im, cax=cax, label="correlation coefficient r")
    return _save(fig, path, layout=False)


def plot_correlation_matrix(
    names: Sequence[str], C: np.ndarray, path: Path, title: str = ""
) -> Path:
    """One signed correlation matrix (signal channels, seed 0 Fig. 7) with its colour bar."""
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    im = _heatmap(ax, names, np.asarray(C, dtype=float), title)
    fig.colorbar(im, ax=ax, label="correlation coefficient r", fraction=0.046, pad=0.04)
    return _save(fig, path)


def excited_bins(amp: np.ndarray, rel: float = 1e-2) -> np.ndarray:
    """Bins of an amplitude spectrum above ``rel`` x its largest non-DC line: the excited
    harmonics of a multisine (the other bins hold only leakage and rounding)."""
    a = np.asarray(amp, dtype=float).copy()
    if a.size < 2:
        return np.zeros(0, dtype=int)
    a[0] = 0.0  # the mean (a vertex offset) is no harmonic
    top = float(np.max(a))
    if top <= 0.0:
        return np.zeros(0, dtype=int)
    return np.nonzero(a > rel * top)[0]


def plot_spectra(
    t: np.ndarray,
    u: np.ndarray,
    names: Sequence[str],
    harmonics: Sequence[Optional[Sequence[int]]],
    f0: float,
    path: Path,
    title: str = "",
) -> Path:
    """Amplitude spectra of the designed multisines, one panel per channel (seed 0 Sec. V):
    |DFT| x 2/N of the record (one or more whole periods), the channel's excited harmonics
    k f0 marked (dots) and the other bins (leakage, other channels' harmonics) in grey; x range
    up to 1.25x the channel's highest harmonic. A channel whose harmonics are not given (a
    ``fly`` run keeps ``signals.npz`` without ``summary.yaml``) has them read from its
    spectrum (:func:`excited_bins`) and says so in its title."""
    u = np.asarray(u, dtype=float)
    N, n = u.shape
    amp = np.abs(np.fft.rfft(u, axis=0)) * 2.0 / N
    freq = np.fft.rfftfreq(N, d=float(np.median(np.diff(t))))
    df = float(freq[1]) if freq.size > 1 else 1.0
    cols = 2 if n > 3 else 1
    rows = int(math.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(11, 2.1 * rows + 0.8), squeeze=False)
    for i in range(n):
        ax = axes[i // cols][i % cols]
        hi = harmonics[i]
        given = hi is not None and len(hi) > 0
        if given:  # harmonic k is at k f0: its bin on this record's frequency grid
            k = np.asarray(hi, dtype=float)
            h = np.rint(k * float(f0) / df).astype(int)
        else:
            h = excited_bins(amp[:, i])
        h = h[(h >= 0) & (h < freq.size)]
        how = "" if given or not h.size else " (read from the spectrum)"
        fmax = 1.25 * float(freq[h].max()) if h.size else float(freq[-1])
        sel = freq <= fmax
        ax.vlines(freq[sel], 0, amp[sel, i], color="0.65", lw=0.8)
        if h.size:
            ax.vlines(freq[h], 0, amp[h, i], color="C0", lw=1.2)
            ax.plot(freq[h], amp[h, i], "o", color="C0", ms=3, label="excited harmonic")
        ax.set_xlim(0, fmax)
        # headroom above the tallest line: the legend sits there, not on a harmonic
        top = float(np.max(amp[sel, i])) if np.any(sel) else 0.0
        ax.set_ylim(0, 1.35 * top if top > 0 else 1.0)
        ax.set_title(f"{names[i]}: {h.size} harmonics{how}", fontsize=9)
        ax.set_ylabel("amplitude", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        if i == 0 and h.size:
            ax.legend(fontsize=7, loc="upper right")
    for i in range(n, rows * cols):
        axes[i // cols][i % cols].axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("frequency [Hz]", fontsize=8)
    if n % cols:
        axes[-2][-1].set_xlabel("frequency [Hz]", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plot_margins(m: RunMargins, path: Path, title: str = "") -> Path:
    """Safety margins over time (:mod:`lpv_sysid.report.margins`): tilt vs its limit, ESC
    headroom vs saturation, distance to the box edge vs the box and the supervisor's margin, and
    the bound-monitor ratio vs gamma x margin (and gamma)."""
    L = m.limits
    fig, axes = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    ax = axes[0]
    ax.plot(m.t, m.tilt_deg, lw=0.8, label=f"max(|phi|, |theta|) ({m.state_source})")
    ax.axhline(L.max_tilt_deg, color="r", ls="--", lw=1, label=f"limit {L.max_tilt_deg:g} deg")
    ax.set_ylim(0, 1.08 * max(L.max_tilt_deg, float(np.nanmax(m.tilt_deg))))
    ax.set_ylabel("tilt [deg]")
    ax = axes[1]
    ax.plot(m.t, 100 * m.esc_headroom, lw=0.8, label="min over motors of min(u_ESC, 1 - u_ESC)")
    ax.axhline(0, color="r", ls="--", lw=1, label="saturation")
    ax.set_ylim(-2, 52)
    ax.set_ylabel("ESC headroom [%]")
    ax = axes[2]
    ax.plot(m.t, m.box_distance, lw=0.8, label="distance of (u, v, w) to the nearest box face")
    ax.axhline(0, color="k", ls="-", lw=0.8, label="box edge")
    ax.axhline(-L.box_margin, color="r", ls="--", lw=1, label="supervisor stop")
    # headroom above the largest distance: the legend sits there, not on the trace
    lo = min(-L.box_margin, float(np.nanmin(m.box_distance)))
    hi = max(0.0, float(np.nanmax(m.box_distance)))
    ax.set_ylim(lo - 0.1 * (hi - lo), hi + 0.45 * (hi - lo))
    ax.set_ylabel("to box edge [m/s]")
    ax = axes[3]
    ax.plot(m.t, m.monitor_ratio, lw=0.8, label="running ||z|| / ||u_e||")
    if L.monitor_limit is not None:
        ax.axhline(L.monitor_limit, color="r", ls="--", lw=1, label="limit gamma x margin")
        ax.axhline(float(L.gamma or 0.0), color="0.4", ls=":", lw=1, label="gamma")
        top = max(
            L.monitor_limit,
            float(np.nanmax(m.monitor_ratio)) if np.any(np.isfinite(m.monitor_ratio)) else 0.0,
        )
        ax.set_ylim(0, 1.1 * top)
    ax.set_ylabel("bound monitor")
    ax.set_xlabel("t [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best", ncol=3, framealpha=0.85)
    if title:
        axes[0].set_title(title)
    return _save(fig, path)


def plot_flown_phase2(
    t: np.ndarray,
    v: np.ndarray,
    v_d: np.ndarray,
    u: np.ndarray,
    sent: np.ndarray,
    path: Path,
    title: str,
    box: Optional[tuple[Sequence[float], Sequence[float]]] = None,
    max_error: Optional[float] = None,
    input_limits: Optional[Sequence[tuple[float, float]]] = None,
    input_names: Sequence[str] = ("thrust", "p_sp", "q_sp", "r_sp"),
    signal: Optional[tuple[float, float]] = None,
    abort: Optional[tuple[float, str]] = None,
) -> Path:
    """A flown phase-2 run (``fly phase2``): body velocity u, v, w against v_d with the
    scheduling ``box`` edges (dotted), the tracking-error limit v_d +- ``max_error`` that hands
    back (grey band), the signal window (shaded) and the ``abort`` (time, reason: red line);
    below, the rate-plant inputs the law computed (thin) and sent after the clip (thick) with
    their ``input_limits``."""
    fig, axes = plt.subplots(3 + u.shape[1], 1, figsize=(8, 2.0 * (3 + u.shape[1])), sharex=True)
    for i in range(3):
        ax = axes[i]
        if max_error is not None:
            ax.fill_between(
                t,
                v_d[:, i] - max_error,
                v_d[:, i] + max_error,
                color="0.85",
                lw=0,
                label=f"|v - v_d| <= {max_error:g} m/s",
            )
        ax.plot(t, v[:, i], lw=1.0, label="v")
        ax.plot(t, v_d[:, i], "k--", lw=1.0, label="v_d")
        if box is not None:
            for edge in (box[0][i], box[1][i]):
                ax.axhline(float(edge), color="0.4", ls=":", lw=0.8)
        ax.set_ylabel(VEL_LABELS[i])
    for j in range(u.shape[1]):
        ax = axes[3 + j]
        ax.plot(t, u[:, j], lw=0.6, color="0.5", label="law")
        ax.plot(t, sent[:, j], lw=1.0, label="sent")
        if input_limits is not None and j < len(input_limits):
            for edge in input_limits[j]:
                ax.axhline(float(edge), color="r", ls=":", lw=0.8)
        ax.set_ylabel(str(input_names[j]) if j < len(input_names) else f"u{j}")
    for ax in axes:
        if signal is not None:
            ax.axvspan(signal[0], signal[1], color="tab:green", alpha=0.07)
        if abort is not None:
            ax.axvline(abort[0], color="r", lw=1.2)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=7, ncol=3)
    axes[3].legend(loc="upper right", fontsize=7, ncol=2)
    axes[-1].set_xlabel("t [s] since the first command")
    head = title if abort is None else f"{title}\nABORT at {abort[0]:.2f} s: {abort[1][:80]}"
    axes[0].set_title(head, fontsize=9)
    return _save(fig, path)
