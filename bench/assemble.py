"""Assemble BENCHMARKS.md from the per-topic result pages in bench/results/.

Each page holds the numbers and the exact command that produced them; this script only
concatenates them in a fixed order under a common header (``python -m bench.assemble``).
"""

from __future__ import annotations

from pathlib import Path

ORDER = ["signals", "ident", "synthesis", "phase2", "nodes", "mavlink", "bag", "vrft"]

HEADER = """# Benchmarks

All numbers were measured on the project's 2-core / 24 GiB machine, usually while other jobs
were running (load average 2-5), so they are upper bounds. Each section gives the command that
produced it; `make bench` runs every `bench/bench_*.py`. Timing lives here only: the test suite
asserts no timings.

| target (issue) | measured | status |
|---|---|---|
{targets}
"""


def main() -> None:
    root = Path(__file__).resolve().parent
    targets = (root / "targets.md").read_text().strip()
    parts = [HEADER.format(targets=targets)]
    for name in ORDER:
        page = root / "results" / f"{name}.md"
        if page.is_file():
            text = page.read_text().strip()
            if text.startswith("# "):  # demote page titles to sections
                text = "#" + text
            parts.append(text + "\n")
    (root.parent / "BENCHMARKS.md").write_text("\n".join(parts))


if __name__ == "__main__":
    main()
