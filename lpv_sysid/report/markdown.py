"""Markdown report of a run directory (report.md + PNG figures next to it).

It opens with the go/no-go summary (certificate, ``verification.yaml``, safety margins over the
run, aborts, hand-back, and what was SIMULATED or FLOWN: :mod:`lpv_sysid.report.gonogo`), then
follows the method of seed 0: phase-1 equilibria (Table 1), identification R^2 (Table 2),
validation TIC/NRMSE (Table 3), signal design (spectra, Fig. 7), synthesis certificate
(Lemma 1), the independent verification as recorded, phase-2 gain vs gamma (Eq. 29), tracking
(Figs. 8-9) and regressor correlations (Fig. 10). A section is written only when its input
exists; otherwise the report says which file is missing. Sections:
:mod:`~lpv_sysid.report.sections_design`, :mod:`~lpv_sysid.report.sections_models` (open-loop
poles, time to double, parameter table), :mod:`~lpv_sysid.report.sections_flight`.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Optional

from lpv_sysid.errors import ConfigError
from lpv_sysid.report.data import CANDIDATES, load_run
from lpv_sysid.report.document import Report, md_table
from lpv_sysid.report.sections_design import (
    _ident_section,
    _phase1_section,
    _signals_section,
    _synthesis_section,
    _verification_section,
)
from lpv_sysid.report.sections_flight import (
    _phase2_section,
    flown_phase2_section,
    go_no_go_section,
)
from lpv_sysid.report.sections_models import nonlinear_section, stability_section
from lpv_sysid.report.sections_phase1 import frequency_section, phase1_section

log = logging.getLogger(__name__)

SECTION_INPUTS = {
    "trims": "phase-1 model trims",
    "models": "identified vertex models (Tables 1, 2)",
    "validation": "independent validation (Table 3)",
    "signals_summary": "signal design summary",
    "signals": "signal time histories",
    "gains": "LPV gains + certificate",
    "verification": "independent verification",
    "phase2_summary": "phase-2 simulation",
}


def _inputs_section(r: Report) -> None:
    d = r.data
    r.h(2, "Inputs")
    rows = []
    for key, label in SECTION_INPUTS.items():
        if key in d.problems:
            rows.append([label, "UNREADABLE", d.problems[key]])
        elif key in d.derived:
            rows.append([label, "derived", d.derived[key]])
        elif key in d.found:
            rows.append([label, "found", f"`{d.found[key].relative_to(d.run_dir)}`"])
        else:
            rows.append(
                [label, "missing", "looked for " + ", ".join(f"`{c}`" for c in CANDIDATES[key])]
            )
    for name in ("eq33", "nonlinear"):
        key = f"phase2_{name}"
        if key in d.found:
            rows.append(
                [
                    f"phase-2 {name} time histories",
                    "found",
                    f"`{d.found[key].relative_to(d.run_dir)}`",
                ]
            )
        elif key in d.problems:
            rows.append([f"phase-2 {name} time histories", "UNREADABLE", d.problems[key]])
    r.p(md_table(["input", "status", "file"], rows))
    absent = [
        SECTION_INPUTS[k]
        for k in SECTION_INPUTS
        if (k not in d.found and k not in d.derived) or k in d.problems
    ]
    if absent:
        r.p("Missing or unreadable inputs: " + "; ".join(absent) + ".")
    else:
        r.p("All inputs present.")


def write_report(
    run_dir: str | Path, out_path: Optional[str | Path] = None, verify: bool = True
) -> Path:
    """Write ``report.md`` (default ``RUN/report/report.md``) and its PNG figures; return its path.

    ``verify`` is accepted for compatibility and has no effect: the verification is read from
    ``verification.yaml``; without one the go/no-go table says "not verified" (NO-GO)."""
    data = load_run(run_dir, verify=verify)
    out = Path(out_path) if out_path is not None else data.run_dir / "report" / "report.md"
    if out.suffix.lower() != ".md":
        raise ConfigError(f"out_path: {out} must end in .md")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"out_path: cannot create {out.parent} ({exc.strerror})") from None
    r = Report(data, out)
    r.lines = [
        "# lpv_sysid run report",
        "",
        f"Run directory: `{data.run_dir}`. Method: Hopwood & Woolsey, robust LPV control for "
        "safe and effective unstable-aircraft system identification (seed 0).",
    ]
    go_no_go_section(r)
    _inputs_section(r)
    _phase1_section(r)
    phase1_section(r)
    _ident_section(r)
    stability_section(r)
    frequency_section(r)
    nonlinear_section(r)
    _signals_section(r)
    _synthesis_section(r)
    _verification_section(r)
    _phase2_section(r)
    flown_phase2_section(r)
    text = "\n".join(r.lines).rstrip() + "\n"
    try:
        out.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"out_path: cannot write {out} ({exc.strerror})") from None
    return out
