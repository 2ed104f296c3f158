"""The figures ``lpv-sysid simulate phase2`` writes next to its outputs: per run the tracking
and the perturbation v - v_d, and the Eq. (6) regressor correlation (seed 0 Fig. 10)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

from lpv_sysid.report.gonogo import SIMULATED
from lpv_sysid.report.plots import plot_perturbation, plot_regressor_correlations, plot_tracking
from lpv_sysid.report.sections_flight import regressor_correlations_from_summary
from lpv_sysid.sim.phase2 import RunRecord


def write_phase2_figures(
    out_dir: str | Path,
    records: Sequence[RunRecord],
    regressor_block: Optional[dict] = None,
    box: Optional[tuple[Sequence[float], Sequence[float]]] = None,
) -> dict[str, Path]:
    """Draw the figures of the phase-2 ``records`` (and ``regressor_block`` of its
    ``summary.yaml``) into ``out_dir``; return the written paths by name. Every title says
    SIMULATED (these runs are the package's simulation); ``box``: the scheduling box
    ``(min, max)`` drawn on the tracking plots."""
    out = Path(out_dir)
    written: dict[str, Path] = {}
    for rec in records:
        if rec.t.size < 2:
            continue
        label = f"[{SIMULATED}] {rec.name}"
        written[f"tracking_{rec.name}"] = plot_tracking(
            rec.t, rec.v_d, rec.v, out / f"tracking_{rec.name}.png", label, box
        )
        written[f"perturbation_{rec.name}"] = plot_perturbation(
            rec.t, rec.v - rec.v_d, out / f"perturbation_{rec.name}.png", label
        )
    if regressor_block is not None:
        written["regressor_correlation"] = plot_regressor_correlations(
            regressor_correlations_from_summary(regressor_block),
            out / "regressor_correlation.png",
            f"[{SIMULATED}] Eq. (6) regressor correlation ({regressor_block['source']})",
        )
    return written
