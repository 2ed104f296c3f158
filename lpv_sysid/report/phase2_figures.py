"""The figures ``lpv-sysid simulate phase2`` writes next to its outputs: per run the tracking
and the perturbation v - v_d, and the Eq. (6) regressor correlation (seed 0 Fig. 10)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

from lpv_sysid.report.plots import plot_perturbation, plot_regressor_correlations, plot_tracking
from lpv_sysid.report.sections_flight import regressor_correlations_from_summary
from lpv_sysid.sim.phase2 import RunRecord


def write_phase2_figures(
    out_dir: str | Path, records: Sequence[RunRecord], regressor_block: Optional[dict] = None
) -> dict[str, Path]:
    """Draw the figures of the phase-2 ``records`` (and ``regressor_block`` of its
    ``summary.yaml``) into ``out_dir``; return the written paths by name."""
    out = Path(out_dir)
    written: dict[str, Path] = {}
    for rec in records:
        if rec.t.size < 2:
            continue
        written[f"tracking_{rec.name}"] = plot_tracking(
            rec.t, rec.v_d, rec.v, out / f"tracking_{rec.name}.png", rec.name
        )
        written[f"perturbation_{rec.name}"] = plot_perturbation(
            rec.t, rec.v - rec.v_d, out / f"perturbation_{rec.name}.png", rec.name
        )
    if regressor_block is not None:
        written["regressor_correlation"] = plot_regressor_correlations(
            regressor_correlations_from_summary(regressor_block),
            out / "regressor_correlation.png",
            f"Eq. (6) regressor correlation ({regressor_block['source']})",
        )
    return written
