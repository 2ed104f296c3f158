"""Phase-1 trim table (seed 0 Table 1): achieved vs model equilibria per vertex run,
written as ``trims.yaml`` and ``trims.md``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
import yaml

from lpv_sysid.models.quadrotor import SEED0_TABLE1, TRIM_COLUMNS

if TYPE_CHECKING:
    from lpv_sysid.sim.phase1.config import Phase1Config
    from lpv_sysid.sim.phase1.runs import RunRecord


def trim_table(runs: Sequence[RunRecord], cfg: Phase1Config, arm_length: float) -> list[dict]:
    rows = []
    for rec in runs:
        ach = rec.achieved_trim(cfg.trim_average_s, arm_length)
        x0 = rec.model_trim.x0
        model = dict(zip(TRIM_COLUMNS, [*x0[2:5], *np.degrees(x0[0:2]), *x0[8:12]]))
        row = {
            "run": rec.name,
            "vertex": [float(c) for c in rec.v_d],
            "achieved": ach,
            "model_trim": {k: float(v) for k, v in model.items()},
        }
        k0, k1, k2 = (int(round(c)) for c in rec.v_d)
        key = (k0, k1, k2)
        if key in SEED0_TABLE1:
            row["seed0_table1"] = dict(zip(TRIM_COLUMNS, SEED0_TABLE1[key]))
        rows.append(row)
    return rows


def write_trim_table(rows: Sequence[dict], out_dir: str | Path) -> tuple[Path, Path]:
    """trims.yaml (machine-readable) and trims.md (seed 0 Table 1 layout)."""
    out = Path(out_dir)
    y = out / "trims.yaml"
    y.write_text(
        yaml.safe_dump(
            {
                "format": "lpv_sysid/phase1_trims@1",
                "columns": list(TRIM_COLUMNS),
                "units": [
                    "m/s",
                    "m/s",
                    "m/s",
                    "deg",
                    "deg",
                    "rad/s",
                    "m*rad/s",
                    "m*rad/s",
                    "rad/s",
                ],
                "runs": list(rows),
            },
            sort_keys=False,
        )
    )
    m = out / "trims.md"
    m.write_text(format_trim_table(rows) + "\n")
    return y, m


def format_trim_table(rows: Sequence[dict]) -> str:
    head = "| vertex | source | " + " | ".join(TRIM_COLUMNS) + " |"
    lines = [head, "|" + "---|" * (len(TRIM_COLUMNS) + 2)]
    for row in rows:
        vtx = "[" + " ".join(f"{c:+g}" for c in row["vertex"]) + "]"
        for src in ("achieved", "model_trim", "seed0_table1"):
            if src in row:
                vals = " | ".join(
                    f"{row[src][k]:.2f}" if abs(row[src][k]) < 100 else f"{row[src][k]:.1f}"
                    for k in TRIM_COLUMNS
                )
                lines.append(f"| {vtx} | {src} | {vals} |")
    return "\n".join(lines)
