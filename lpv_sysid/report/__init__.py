"""lpv_sysid.report: the Markdown run report (``lpv-sysid report``).

- :mod:`lpv_sysid.report.data`: find and load the artefacts of a run directory, extract tables
  (no plotting);
- :mod:`lpv_sysid.ident.nonlinear.correlation`: regressors of seed 0 Eq. (6) and their correlation
(Fig. 10);
- :mod:`lpv_sysid.report.plots`: PNG figures (matplotlib Agg);
- :mod:`lpv_sysid.report.markdown`: ``report.md`` assembly, one section per available input.
"""

from __future__ import annotations

from lpv_sysid.report.data import load_run
from lpv_sysid.report.gonogo import (
    DATA_LABELS,
    FLOWN,
    NO_GO,
    SIMULATED,
    go_no_go,
    provenance,
    vehicle_label,
)
from lpv_sysid.report.margins import limits_from_summary, run_margins
from lpv_sysid.report.markdown import write_report
from lpv_sysid.report.phase2_figures import write_phase2_figures
from lpv_sysid.report.sections_flight import gain_row

__all__ = [
    "DATA_LABELS",
    "FLOWN",
    "NO_GO",
    "SIMULATED",
    "gain_row",
    "go_no_go",
    "limits_from_summary",
    "load_run",
    "provenance",
    "run_margins",
    "vehicle_label",
    "write_phase2_figures",
    "write_report",
]
