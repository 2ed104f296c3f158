"""Validation metrics of seed 0 Sec. IV: TIC (Eq. 24), NRMSE (Eq. 25), R^2, and the Fig. 4 plot.

``xdot_m`` is the modelled state derivative (Eq. 19 / 33 evaluated on measured states and
inputs), ``xdot_f`` the one measured from flight data; both are K-sample columns per axis.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from lpv_sysid.errors import ConfigError

#: the axes of seed 0 Tables 2 and 3 and their indices in the 12-state of DESIGN.md
AXES = ("udot", "vdot", "wdot", "pdot", "qdot", "rdot")
AXIS_INDEX = (2, 3, 4, 5, 6, 7)


def _pair(xm: np.ndarray, xf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xm = np.asarray(xm, dtype=float)
    xf = np.asarray(xf, dtype=float)
    if xm.shape != xf.shape or xm.ndim != 1 or xm.size == 0:
        raise ConfigError(
            f"modelled and measured series must be equal-length 1-D, got {xm.shape}, {xf.shape}"
        )
    if not (np.all(np.isfinite(xm)) and np.all(np.isfinite(xf))):
        raise ConfigError("modelled or measured series contains NaN or inf")
    return xm, xf


def tic(xdot_m: np.ndarray, xdot_f: np.ndarray) -> float:
    """Theil's inequality coefficient, seed 0 Eq. (24); 0 = perfect, 1 = worst."""
    xm, xf = _pair(xdot_m, xdot_f)
    k = xm.size
    num = np.sqrt((xm - xf) @ (xm - xf) / k)
    den = np.sqrt(xm @ xm / k) + np.sqrt(xf @ xf / k)
    return float(num / den) if den > 0 else 0.0


def nrmse(xdot_m: np.ndarray, xdot_f: np.ndarray) -> float:
    """Normalised RMS error, seed 0 Eq. (25): RMS error divided by range(xdot_f)."""
    xm, xf = _pair(xdot_m, xdot_f)
    rng = float(np.max(xf) - np.min(xf))
    if rng == 0:
        raise ConfigError("NRMSE undefined: the measured series is constant (zero range)")
    return float(np.sqrt((xm - xf) @ (xm - xf) / xm.size) / rng)


def r_squared(y: np.ndarray, y_hat: np.ndarray) -> float:
    """Coefficient of determination ``1 - SSE / SST``."""
    y, yh = _pair(y_hat, y)[::-1]
    sst = float((y - y.mean()) @ (y - y.mean()))
    sse = float((y - yh) @ (y - yh))
    return 1.0 - sse / sst if sst > 0 else float(sse == 0)


def axis_metrics(
    xdot_m: np.ndarray,
    xdot_f: np.ndarray,
    axes: Sequence[str] = AXES,
    index: Sequence[int] = AXIS_INDEX,
) -> dict[str, dict[str, float]]:
    """TIC and NRMSE per axis (seed 0 Table 3) from (K, n_x) modelled/measured derivatives."""
    xm = np.asarray(xdot_m, dtype=float)
    xf = np.asarray(xdot_f, dtype=float)
    if xm.shape != xf.shape or xm.ndim != 2:
        raise ConfigError(
            f"modelled/measured derivatives must be equal (K, n_x), got {xm.shape}, {xf.shape}"
        )
    return {
        "tic": {a: tic(xm[:, i], xf[:, i]) for a, i in zip(axes, index)},
        "nrmse": {a: nrmse(xm[:, i], xf[:, i]) for a, i in zip(axes, index)},
    }


def plot_validation(
    t: np.ndarray,
    xdot_m: np.ndarray,
    xdot_f: np.ndarray,
    path: str,
    axes: Sequence[str] = AXES,
    index: Sequence[int] = AXIS_INDEX,
    title: str = "LPV model independent validation (seed 0 Fig. 4)",
) -> str:
    """Measured vs modelled state derivatives, one panel per axis; returns path.

    Drawn on a bare Agg canvas (``matplotlib.figure.Figure``: no pyplot, no global figure
    state) with fixed margins that fit the labels (``tight_layout`` draws the figure once more
    to measure them: about a fifth of the plot's time).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    units = {
        "udot": "m/s^2",
        "vdot": "m/s^2",
        "wdot": "m/s^2",
        "pdot": "rad/s^2",
        "qdot": "rad/s^2",
        "rdot": "rad/s^2",
    }
    height = 1.6 * len(axes)
    fig = Figure(figsize=(8, height))
    FigureCanvasAgg(fig)
    axs = fig.subplots(len(axes), 1, sharex=True, squeeze=False)[:, 0]
    for ax, a, i in zip(axs, axes, index):
        ax.plot(t, xdot_f[:, i], "k-", lw=0.8, label="measured")
        ax.plot(t, xdot_m[:, i], "r--", lw=0.8, label="model")
        ax.set_ylabel(f"{a} [{units.get(a, '')}]")
    axs[0].legend(loc="upper right", fontsize=8)
    axs[0].set_title(title)
    axs[-1].set_xlabel("t [s]")
    # margins in inches: title 0.35, x tick labels and label 0.5, y tick labels and label 0.9
    fig.subplots_adjust(
        left=0.9 / 8, right=1 - 0.15 / 8, top=1 - 0.35 / height, bottom=0.5 / height, hspace=0.15
    )
    fig.savefig(path, dpi=110)
    return path
