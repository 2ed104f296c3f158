"""Assemble BENCHMARKS.md from the result pages in bench/results/ (``python -m bench.assemble``).

The summary table is generated: the rows every benchmark module wrote next to its page
(``<topic>.rows.json``, see bench/harness.py), then the rows of earlier issues kept in
``bench/targets.md`` that no module generates. The synthesis section (``synthesis.md``)
and its row are written by the synthesis benchmark's owner and copied unchanged (its row
from ``synthesis.rows.json`` when present, else from targets.md). The pages follow in a
fixed order; each carries the command that produced it.
"""

from __future__ import annotations

import json
from pathlib import Path

ORDER = [
    "demo",
    "synthesis",
    "phase1",
    "phase2",
    "ident",
    "ident_notes",
    "lpv_law",
    "nodes",
    "mavlink",
    "bag",
    "signals",
    "vrft",
]

HEADER = """# Benchmarks

Measured on the project's 2-core / 24 GiB machine, usually while other jobs were running (each
page gives the load average), so wall times are upper bounds; CPU times are given where the load
made wall time meaningless. Every issue-15 row reports median and spread (10th-90th percentile)
and, where there is one, the floor measured in the same run (product and floor interleaved) with
their ratio. Each section names the command that produced it; `make bench` runs every
`bench/bench_*.py` and then this assembly (`python -m bench.assemble`). Timing lives here only:
the test suite asserts no timings.

| measure (issue) | measured | floor / anchor (same run) | ratio | target | status |
|---|---|---|---|---|---|
{rows}
"""


def _legacy(lines: list[str], generated_keys: set[str]) -> list[str]:
    out = []
    for ln in lines:
        cells = [c.strip() for c in ln.strip().strip("|").split("|")]
        if len(cells) < 3 or cells[0].startswith("---"):
            continue
        if any(k.lower() in cells[0].lower() for k in generated_keys):
            continue
        out.append(f"| {cells[0]} | {cells[1]} | — | — | — | {cells[-1]} |")
    return out


def main() -> None:
    root = Path(__file__).resolve().parent
    results = root / "results"
    rows = []
    for f in sorted(results.glob("*.rows.json")):
        rows.extend(json.loads(f.read_text()))
    rows.sort(key=lambda r: (r.get("order", 100), r["key"]))
    table = [
        f"| {r['key']} ({r['issue']}) | {r['measured']} | {r['floor']} | {r['ratio']} | "
        f"{r['target']} | "
        f"{r['status']} |"
        for r in rows
    ]
    keys = {r["key"] for r in rows}
    legacy = (
        (root / "targets.md").read_text().splitlines() if (root / "targets.md").is_file() else []
    )
    synth = [ln for ln in legacy if "lemma 1" in ln.lower()]
    if not (results / "synthesis.rows.json").is_file():
        table[1:1] = _legacy(synth, set())  # the synthesis row right after the demo row
    table += _legacy(
        [ln for ln in legacy if ln not in synth],
        keys
        | {
            "make demo",
            "MAVLink decode",
            "runtime LPV law",
            "controller node path",
            "replay of a 60 s",
            "identify 8 vertices",
            "telemetry-in",
        },
    )
    parts = [HEADER.format(rows="\n".join(table))]
    for name in ORDER + sorted(p.stem for p in results.glob("*.md") if p.stem not in ORDER):
        page = results / f"{name}.md"
        if page.is_file():
            text = page.read_text().strip()
            if text.startswith("# "):  # demote page titles to sections
                text = "#" + text
            parts.append(text + "\n")
    (root.parent / "BENCHMARKS.md").write_text("\n".join(parts))


if __name__ == "__main__":
    main()
