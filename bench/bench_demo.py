"""`make demo` end to end (issue 15 target < 45 s): ``python -m lpv_sysid.cli.main demo``
exactly as the Makefile runs it (after install), with the time of each of its steps.

    .venv/bin/python -m bench.bench_demo [--repeat N]
"""

from __future__ import annotations

import argparse
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.harness import Page, Row, Stat, load_average, repo_root, status

# the demo's step banners are INFO log lines on stderr: "INFO lpv_sysid.cli.demo: [k/n] ..."
_PREFIX = r"^(?:\w+ lpv_sysid\.cli\.demo: )?"
STEP = re.compile(_PREFIX + r"\[(\d+)/(\d+)\] (.*?)(?:: lpv-sysid .*)?$")
DONE = re.compile(_PREFIX + r"\[(\d+)/(\d+)\] done in ([0-9.]+) s$")


def run_once() -> tuple[float, float, dict]:
    out = Path(tempfile.mkdtemp(prefix="bench_demo_"))
    try:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        p = subprocess.run(
            [sys.executable, "-m", "lpv_sysid.cli.main", "demo", "--out", str(out / "demo_out")],
            cwd=repo_root(),
            capture_output=True,
            text=True,
        )
        wall = time.perf_counter() - w0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        failure = None
        if p.returncode != 0:
            err = [ln for ln in p.stderr.splitlines() if "error" in ln]
            failure = err[-1] if err else f"exit status {p.returncode}"
        titles, steps = {}, {}
        for line in p.stderr.splitlines() + p.stdout.splitlines():
            m = DONE.match(line)
            if m:
                steps[int(m.group(1))] = float(m.group(3))
                continue
            m = STEP.match(line)
            if m:
                titles[int(m.group(1))] = m.group(3)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return wall, cpu, {k: (titles.get(k, "?"), v) for k, v in steps.items()}, failure
    finally:
        shutil.rmtree(out, ignore_errors=True)


def _largest(steps: dict) -> str:
    k, (title, v) = max(steps.items(), key=lambda kv: Stat(kv[1][1]).median)
    rest = sum(Stat(x).median for kk, (_, x) in steps.items() if kk != k)
    name = title.split(" (")[0]
    return f"step {k} ({name}) takes {Stat(v).median:.0f} s, the other steps {rest:.0f} s together"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args(argv)
    load0 = load_average()
    page = Page(
        "demo",
        "`make demo` end to end (issue 15)",
        f".venv/bin/python -m bench.bench_demo --repeat {args.repeat}",
    )
    runs = [run_once() for _ in range(args.repeat)]
    wall, cpu = Stat([r[0] for r in runs]), Stat([r[1] for r in runs])
    failures = [r[3] for r in runs if r[3]]
    steps = {}
    for _, _, s, _ in runs:
        for k, (title, sec) in s.items():
            steps.setdefault(k, (title, []))[1].append(sec)
    page.add(
        "`python -m lpv_sysid.cli.main demo --out DIR` in a subprocess (the venv exists: the "
        "Makefile's install step is not timed)."
    )
    page.add()
    lines = [[f"{k}. {title}", Stat(v).fmt(1, "s")] for k, (title, v) in sorted(steps.items())]
    lines += [["total wall", wall.fmt(1, "s")], ["total CPU (user + sys)", cpu.fmt(1, "s")]]
    page.table(["step", "wall median [p10-p90]"], lines)
    if failures:
        page.add(
            f"The demo did not finish: `{failures[0]}` (the totals cover the steps that ran)."
        )
        page.add()
    done = "" if not failures else f" (stopped: {failures[0]})"
    page.rows.append(
        Row(
            "`make demo` (after install)",
            "15",
            f"{wall.median:.0f} s wall, {cpu.median:.0f} s CPU; steps: "
            + ", ".join(
                f"{title.split(' (')[0].split(' at ')[0]} {Stat(v).median:.1f} s"
                for _, (title, v) in sorted(steps.items())
            )
            + done,
            target="< 45 s",
            status=status(
                None if failures else wall.median < 45.0,
                "did not complete"
                if failures
                else ("" if wall.median < 45.0 else _largest(steps)),
            ),
            order=2,
        )
    )
    page.write(load0)


if __name__ == "__main__":
    main()
