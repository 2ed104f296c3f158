"""Figure of a signal set like seed 0 Figs. 5-7: time histories (normalised to unit
amplitude), power spectra, and the correlation matrix. Uses the Agg canvas directly
(no pyplot, no global backend state)."""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FormatStrFormatter

from lpv_sysid.errors import ConfigError
from lpv_sysid.signals import metrics
from lpv_sysid.signals.multisine import SignalSet


def _label_column(ax, j: int, n: int, xlabel: str, title: str) -> None:
    """Row ``j`` of a column of ``n`` stacked axes sharing the x range: x tick labels and
    the x label on the bottom one only, the column title on the top one."""
    if j < n - 1:
        ax.set_xticklabels([])
    else:
        ax.set_xlabel(xlabel)
    if j == 0:
        ax.set_title(title)


def signal_figure(sig: SignalSet) -> Figure:
    n = len(sig.names)
    fig = Figure(figsize=(14, max(6.0, 1.1 * n + 1)))
    FigureCanvasAgg(fig)
    gs = fig.add_gridspec(n, 3, width_ratios=[2.2, 1.6, 1.4], wspace=0.35, hspace=0.15)
    f, P = metrics.power_spectrum(sig.u, sig.sample_rate)
    fmax = max(h.max() for h in sig.harmonics) * sig.f0 * 1.1
    for j, name in enumerate(sig.names):
        x = sig.u[:, j]
        ax = fig.add_subplot(gs[j, 0])
        ax.plot(sig.t, x / np.max(np.abs(x)), lw=0.6)
        ax.set_ylabel(name, rotation=0, ha="right", va="center")
        ax.set_ylim(-1.1, 1.1)
        ax.set_yticks([-1, 0, 1])
        _label_column(ax, j, n, "time, s", "time histories (normalised, Fig. 5)")
        ax2 = fig.add_subplot(gs[j, 1])
        pj = P[:, j] / P[:, j].max()
        db = 10 * np.log10(np.maximum(pj, 1e-12))
        h = sig.harmonics[j]
        ax2.vlines(f[h], -60, db[h], lw=0.6)
        ax2.set_xscale("log")
        ax2.xaxis.set_major_formatter(FormatStrFormatter("%g"))  # plain labels, no mathtext
        ax2.set_xlim(sig.f0 * 0.9, fmax)
        ax2.set_ylim(-60, 5)
        ax2.text(
            0.98, 0.1, f"RPF {sig.rpf[j]:.3f}", transform=ax2.transAxes, ha="right", fontsize=8
        )
        _label_column(ax2, j, n, "frequency, Hz", "power, dB (Fig. 6)")
    axc = fig.add_subplot(gs[:, 2])
    c = metrics.correlation_matrix(sig.u)
    im = axc.imshow(c, vmin=-1, vmax=1, cmap="RdBu_r")
    axc.set_xticks(range(n), sig.names, rotation=90)
    axc.set_yticks(range(n), sig.names)
    for i in range(n):
        for k in range(i + 1):
            axc.text(
                k, i, f"{c[i, k]:+.0e}" if i != k else "1", ha="center", va="center", fontsize=5
            )
    axc.set_title("correlation (Fig. 7)")
    fig.colorbar(im, ax=axc, shrink=0.6)
    return fig


def save_figure(path: str, sig: SignalSet) -> None:
    try:
        signal_figure(sig).savefig(path, dpi=110, bbox_inches="tight")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write figure ({exc.strerror})") from None
