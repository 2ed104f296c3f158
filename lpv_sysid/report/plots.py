"""Report figures (matplotlib, Agg backend; no data loading here).

Each function takes arrays and an output path, writes one PNG and returns the path.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lpv_sysid.report.regressors import AXIS_TITLES, RegressorCorrelation  # noqa: E402

VEL_LABELS = ("u [m/s]", "v [m/s]", "w [m/s]")


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_tracking(
    t: np.ndarray, v_d: np.ndarray, v: np.ndarray, path: Path, title: str = ""
) -> Path:
    """Body velocity (solid) and reference (black dashed), like seed 0 Fig. 8."""
    fig, axes = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
    for i, ax in enumerate(axes):
        ax.plot(t, v[:, i], lw=1.0, label="v")
        ax.plot(t, v_d[:, i], "k--", lw=1.0, label="v_d")
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


def _heatmap(ax, names: Sequence[str], C: np.ndarray, title: str) -> None:
    M = np.ma.masked_invalid(C)
    im = ax.imshow(np.abs(M), vmin=0.0, vmax=1.0, cmap="viridis")
    n = len(names)
    ax.set_xticks(range(n))
    ax.set_yticks(range(n))
    ax.set_xticklabels(names, rotation=60, ha="right", fontsize=6)
    ax.set_yticklabels(names, fontsize=6)
    for i in range(n):
        for j in range(n):
            val = C[i, j]
            txt = "-" if not np.isfinite(val) else f"{val:+.2f}"
            ax.text(
                j,
                i,
                txt,
                ha="center",
                va="center",
                fontsize=5,
                color="w" if not np.isfinite(val) or abs(val) < 0.6 else "k",
            )
    ax.set_title(title, fontsize=8)
    return im


def plot_regressor_correlations(
    corrs: Sequence[RegressorCorrelation], path: Path, title: str = ""
) -> Path:
    """Correlation coefficients of the Eq. (6) regressors per axis, like seed 0 Fig. 10."""
    fig, axes = plt.subplots(2, 3, figsize=(12, 8))
    for ax, rc in zip(axes.ravel(), corrs):
        _heatmap(ax, rc.names, rc.corr, AXIS_TITLES.get(rc.axis, rc.axis))
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def plot_correlation_matrix(
    names: Sequence[str], C: np.ndarray, path: Path, title: str = ""
) -> Path:
    """One correlation matrix (signal channels, seed 0 Fig. 7)."""
    fig, ax = plt.subplots(figsize=(5.5, 5))
    _heatmap(ax, names, np.asarray(C, dtype=float), title)
    return _save(fig, path)


def plot_signals(
    t: np.ndarray, u: np.ndarray, names: Sequence[str], path: Path, title: str = ""
) -> Path:
    """Reference and excitation channels normalised to unit amplitude (seed 0 Fig. 5)."""
    n = u.shape[1]
    fig, axes = plt.subplots(n, 1, figsize=(8, 1.1 * n + 1), sharex=True)
    axes = np.atleast_1d(axes)
    for i, ax in enumerate(axes):
        peak = np.max(np.abs(u[:, i])) or 1.0
        ax.plot(t, u[:, i] / peak, lw=0.7)
        ax.set_ylabel(str(names[i]), fontsize=7)
        ax.set_ylim(-1.1, 1.1)
    axes[-1].set_xlabel("t [s]")
    if title:
        axes[0].set_title(title)
    return _save(fig, path)
