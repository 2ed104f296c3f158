"""Studies on both cores (issue 27 item 4): ``lpv-sysid verify --full-box 4000`` and
``lpv-sysid coverage --airframes 4`` serially (``--workers 1``) and on every core
(``--workers 2`` here), interleaved so both see the same machine load, each in its own
subprocess exactly as a user runs it (process start-up included), with the outputs compared
byte for byte (``verification.yaml`` without its ``created`` stamp, ``coverage.yaml``).

    .venv/bin/python -m bench.bench_studies [--run DEMO_DIR] [--repeat N] [--airframes 4]
        [--full-box 4000] [--workers 2]

``--run``: a ``demo`` output directory (gains.yaml, vertex_models.yaml); default: one is made
with ``lpv-sysid demo --quick`` first (not timed). The package's bytecode is compiled first
(``compileall``, not timed), as in an installed package.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.harness import Page, Row, Stat, load_average, repo_root, status

TARGET = 1.6


def _lpv(args: list, cwd: Path) -> tuple[float, float, float, str]:
    """(wall, CPU of the process tree, load average at the start, stdout) of one CLI run."""
    load = load_average()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0 = time.perf_counter()
    p = subprocess.run(
        [sys.executable, "-m", "lpv_sysid.cli.main", *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - w0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode not in (0, 1):
        raise SystemExit(f"lpv-sysid {' '.join(map(str, args))}: exit {p.returncode}\n{p.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, load, p.stdout


def _phase_driver(cli_args: list) -> int:
    """``lpv-sysid <cli_args>`` in this process with the CPU time (this process's, all its
    threads; the workers' from RUSAGE_CHILDREN) at the phases of a pooled study printed as the
    last line of stderr (JSON): ``start`` when the pool is started (the serial prefix),
    ``wait`` when this process has done its own work and waits for the workers, ``collected``
    when the workers are done (``workers``: their CPU), ``end`` at exit."""
    import json

    from lpv_sysid.cli.main import main as cli_main
    from lpv_sysid.parallel import pool

    marks: dict = {}
    init, results = pool.Batch.__init__, pool.Batch.results

    def children() -> float:
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        return r.ru_utime + r.ru_stime

    def init_(self, fn, items, n, backend):  # type: ignore[no-untyped-def]
        if n > 1 and "start" not in marks:
            marks["start"] = time.process_time()
        init(self, fn, items, n, backend)

    def results_(self, on_result=None):  # type: ignore[no-untyped-def]
        pooled = self._n > 1
        if pooled:
            marks["wait"] = time.process_time()
        out = results(self, on_result)
        if pooled:
            marks["collected"] = time.process_time()
            marks["workers"] = children()
        return out

    pool.Batch.__init__ = init_  # type: ignore[method-assign]
    pool.Batch.results = results_  # type: ignore[method-assign]
    rc = cli_main(cli_args)
    marks["end"] = time.process_time()
    print(json.dumps(marks), file=sys.stderr)
    return rc


def _phases(args: list, cwd: Path) -> dict:
    """:func:`_phase_driver` of one CLI run in its own subprocess."""
    import json

    p = subprocess.run(
        [sys.executable, "-m", "bench.bench_studies", "--phase-driver", *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
    )
    if p.returncode not in (0, 1):
        raise SystemExit(
            f"phase driver {' '.join(map(str, args))}: exit {p.returncode}\n{p.stderr}"
        )
    return json.loads(p.stderr.strip().splitlines()[-1])


def _without_stamp(path: Path) -> str:
    return re.sub(r"(?m)^created: .*$", "", path.read_text())


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["--phase-driver"]:
        raise SystemExit(_phase_driver(argv[1:]))
    ap = argparse.ArgumentParser()
    ap.add_argument("--run", type=Path, default=None, help="demo output directory")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--airframes", type=int, default=4)
    ap.add_argument("--full-box", type=int, default=4000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-coverage", action="store_true")
    ap.add_argument(
        "--cpu-phases",
        action="store_true",
        help="also run verify --repeat times per worker count with the CPU time of its phases "
        "(serial prefix, own work beside the workers, workers, tail): the 2-core wall time a "
        "quiet machine would give, when the machine is not quiet",
    )
    args = ap.parse_args(argv)
    # the package's bytecode compiled once, as an installed package has it: with
    # PYTHONDONTWRITEBYTECODE in the environment every run would otherwise compile ~180 modules
    # (~0.15 s of serial start-up in each run, none of it the studies')
    subprocess.run(
        [sys.executable, "-m", "compileall", "-q", str(repo_root() / "lpv_sysid")], check=True
    )
    load0 = load_average()
    tmp = Path(tempfile.mkdtemp(prefix="bench_studies_"))
    try:
        run = args.run
        if run is None:
            run = tmp / "demo"
            _lpv(["demo", "--quick", "--out", run], repo_root())
        page = Page(
            "studies",
            "Studies on both cores (issue 27 item 4)",
            f".venv/bin/python -m bench.bench_studies --repeat {args.repeat} --airframes "
            f"{args.airframes} --full-box {args.full_box} --workers {args.workers}"
            + (" --cpu-phases" if args.cpu_phases else "")
            + (" --skip-coverage" if args.skip_coverage else ""),
        )
        cases = {
            f"verify --full-box {args.full_box}": lambda w, out: [
                "verify",
                "--gains",
                run / "gains.yaml",
                "--models",
                run / "vertex_models.yaml",
                "--full-box",
                args.full_box,
                "--workers",
                w,
                "--out",
                out / "verification.yaml",
            ],
        }
        if not args.skip_coverage:
            cases[f"coverage --airframes {args.airframes}"] = lambda w, out: [
                "coverage",
                "--airframes",
                args.airframes,
                "--workers",
                w,
                "--out",
                out,
            ]
        results: dict = {}
        loads: list = []
        for name, argf in cases.items():
            same = True
            for r in range(args.repeat):
                texts = {}
                for w in (1, args.workers) if r % 2 == 0 else (args.workers, 1):
                    out = tmp / f"{abs(hash(name))}_{w}"
                    shutil.rmtree(out, ignore_errors=True)
                    out.mkdir(parents=True)
                    wall, cpu, load, _ = _lpv(argf(w, out), repo_root())
                    loads.append(load)
                    results.setdefault((name, w), ([], []))
                    results[(name, w)][0].append(wall)
                    results[(name, w)][1].append(cpu)
                    f = "verification.yaml" if name.startswith("verify") else "coverage.yaml"
                    texts[w] = _without_stamp(out / f)
                same = same and texts[1] == texts[args.workers]
            results[(name, "same")] = same
        page.add(
            f"Each command in its own subprocess (`python -m lpv_sysid.cli.main ...`, start-up "
            f"included), `--workers 1` and `--workers {args.workers}` interleaved, "
            f"{args.repeat} runs each; CPU is user + sys of the process tree. Load average at "
            f"the start of the runs: {min(loads):.1f}-{max(loads):.1f} (other jobs share the "
            f"{os.cpu_count()} cores). Outputs compared byte for byte (verification.yaml "
            "without its `created` stamp)."
        )
        page.add()
        lines = []
        for name in cases:
            s_wall, s_cpu = map(Stat, results[(name, 1)])
            p_wall, p_cpu = map(Stat, results[(name, args.workers)])
            speed = s_wall.median / p_wall.median
            lines.append(
                [
                    f"`{name}`",
                    s_wall.fmt(1, "s"),
                    s_cpu.fmt(1, "s"),
                    p_wall.fmt(1, "s"),
                    p_cpu.fmt(1, "s"),
                    f"{speed:.2f}x",
                    "yes" if results[(name, "same")] else "NO",
                ]
            )
            page.rows.append(
                Row(
                    f"studies on both cores: `{name}`",
                    "27",
                    f"{p_wall.median:.2f} s wall on {args.workers} workers vs {s_wall.median:.2f}"
                    f" s serial (CPU {p_cpu.median:.1f} / {s_cpu.median:.1f} s); outputs "
                    + ("identical" if results[(name, "same")] else "DIFFER"),
                    f"serial {s_wall.median:.2f} s",
                    f"{speed:.2f}x faster",
                    f">= {TARGET}x, identical results",
                    status(
                        speed >= TARGET and results[(name, "same")],
                        f"load average {min(loads):.1f}-{max(loads):.1f} during the runs",
                    ),
                    order=40,
                )
            )
        page.table(
            [
                "study",
                "serial wall",
                "serial CPU",
                f"{args.workers} workers wall",
                f"{args.workers} workers CPU",
                "speed-up",
                "identical",
            ],
            lines,
        )
        if args.cpu_phases:
            _cpu_phase_section(page, args, cases, tmp)
        page.write(load0)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _cpu_phase_section(page: Page, args: argparse.Namespace, cases: dict, tmp: Path) -> None:
    """The verify case's CPU phases (:func:`_phase_driver`), serial and pooled interleaved,
    and the wall time of the pooled run on 2 idle cores they imply: the serial prefix + the
    makespan of the parent's own work and the workers' + the tail. Independent of the other
    jobs on the machine (CPU time, not wall time), which only inflate both runs alike."""
    name = next(n for n in cases if n.startswith("verify"))
    serial, pooled, loads = [], [], []
    for r in range(args.repeat):
        for w in (1, args.workers) if r % 2 == 0 else (args.workers, 1):
            out = tmp / f"phases_{w}"
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir(parents=True)
            loads.append(load_average())
            m = _phases(cases[name](w, out), repo_root())
            (serial if w == 1 else pooled).append(m)
    s_cpu = Stat([m["end"] for m in serial])
    prefix = Stat([m["start"] for m in pooled])
    own = Stat([m["collected"] - m["start"] for m in pooled])
    workers = Stat([m["workers"] for m in pooled])
    tail = Stat([m["end"] - m["collected"] for m in pooled])
    est = [
        m["start"]
        + max((m["collected"] - m["start"] + m["workers"]) / 2, m["collected"] - m["start"])
        + (m["end"] - m["collected"])
        for m in pooled
    ]
    e = Stat(est)
    speed = s_cpu.median / e.median
    page.add()
    page.add(
        f"CPU phases of `{name}` (`--cpu-phases`: the same command in-process under "
        "`bench.bench_studies --phase-driver`, CPU time per phase; load average "
        f"{min(loads):.1f}-{max(loads):.1f} at the starts). Serial: one process, its CPU is "
        f"its wall time on an idle core. {args.workers} workers: the parent's serial prefix "
        "before the pool starts, its own work beside the workers (the other checks, the "
        "extreme corners) and the workers' CPU, then the tail (results, "
        "verification.yaml); on 2 idle cores the pooled run takes prefix + max((own + "
        "workers) / 2, own) + tail."
    )
    page.add()
    page.table(
        [
            "serial CPU",
            "prefix",
            "own work beside the workers",
            "workers",
            "tail",
            "2-core wall implied",
            "speed-up implied",
        ],
        [
            [
                s_cpu.fmt(1, "s"),
                prefix.fmt(1, "s"),
                own.fmt(1, "s"),
                workers.fmt(1, "s"),
                tail.fmt(1, "s"),
                e.fmt(1, "s"),
                f"{speed:.2f}x",
            ]
        ],
    )


if __name__ == "__main__":
    main()
