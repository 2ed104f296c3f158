"""Measurement helpers shared by the bench_*.py modules (issue 15 protocol).

Every benchmark row reports the median and the spread (10th-90th percentile, n samples) of
the product's default path and, where the issue names one, a *floor* measured in the same
run -- product and floor batches alternate, so both see the same machine load -- and their
ratio. CPU time (``time.process_time``) is reported next to wall time where the 2-core
machine is shared: other jobs stretch wall time, CPU time much less.

Each module writes ``bench/results/<topic>.md`` (its section of BENCHMARKS.md, with the
command that produced it) and ``bench/results/<topic>.rows.json`` (its rows of the
summary table); ``python -m bench.assemble`` builds BENCHMARKS.md from them.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Optional, Sequence

RESULTS = Path(__file__).resolve().parent / "results"


def load_average() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def percentile(xs: Sequence[float], q: float) -> float:
    s = sorted(xs)
    if not s:
        return float("nan")
    k = (len(s) - 1) * q
    lo, hi = int(k), min(int(k) + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (k - lo)


@dataclass
class Stat:
    """Samples of one quantity (seconds per call unless ``unit`` says otherwise)."""

    samples: list
    unit: str = "s"

    @property
    def median(self) -> float:
        return statistics.median(self.samples)

    @property
    def p10(self) -> float:
        return percentile(self.samples, 0.10)

    @property
    def p90(self) -> float:
        return percentile(self.samples, 0.90)

    @property
    def p99(self) -> float:
        return percentile(self.samples, 0.99)

    def fmt(self, scale: float = 1.0, unit: str = "", digits: int = 3) -> str:
        """``median [p10-p90]`` scaled (e.g. 1e6 for us)."""
        f = f"{{:.{digits}g}}"
        return (
            f"{f.format(self.median * scale)} {unit} [{f.format(self.p10 * scale)}-"
            f"{f.format(self.p90 * scale)}, n={len(self.samples)}]"
        ).replace("  ", " ")


def interleaved(
    fns: Mapping[str, Callable[[], object]],
    number: int,
    repeat: int,
    clock: Callable[[], float] = time.perf_counter,
    warmup: int = 1,
) -> dict[str, Stat]:
    """Per-call time of each callable: ``repeat`` rounds, each running every callable
    ``number`` times in turn (so a product and its floor share the machine's load)."""
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    out = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0 = clock()
            for _ in range(number):
                fn()
            out[k].append((clock() - t0) / number)
    return {k: Stat(v) for k, v in out.items()}


def timed(fn: Callable[[], object], repeat: int = 3) -> tuple[Stat, Stat, object]:
    """(wall Stat, CPU Stat, last result) of ``repeat`` calls of ``fn``."""
    wall, cpu, res = [], [], None
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        res = fn()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return Stat(wall), Stat(cpu), res


@dataclass
class Row:
    """One row of the BENCHMARKS.md summary table."""

    key: str  # the issue's measure, e.g. "phase-1 simulation"
    issue: str  # issue number(s)
    measured: str  # what was measured, with median and spread
    floor: str = "—"  # the floor / anchor, measured in the same run
    ratio: str = "—"  # product / floor
    target: str = "—"
    status: str = ""  # "met", "not met: <why>", "recorded"
    order: int = 100  # position in the summary table


@dataclass
class Page:
    topic: str
    title: str
    command: str
    rows: list = field(default_factory=list)
    text: list = field(default_factory=list)

    def add(self, line: str = "") -> None:
        self.text.append(line)

    def table(self, header: Sequence[str], lines: Sequence[Sequence[object]]) -> None:
        self.add("| " + " | ".join(header) + " |")
        self.add("|" + "---|" * len(header))
        for ln in lines:
            self.add("| " + " | ".join(str(c) for c in ln) + " |")
        self.add()

    def write(self, load_before: float) -> Path:
        RESULTS.mkdir(exist_ok=True)
        head = [
            f"# {self.title}",
            "",
            f"Command: `{self.command}` ({machine()}; load average {load_before:.1f} before, "
            f"{load_average():.1f} after; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}).",
            "",
        ]
        path = RESULTS / f"{self.topic}.md"
        path.write_text("\n".join(head + self.text).rstrip() + "\n")
        (RESULTS / f"{self.topic}.rows.json").write_text(
            json.dumps([asdict(r) for r in self.rows], indent=1) + "\n"
        )
        print("\n".join(head + self.text))
        return path


def machine() -> str:
    return (
        f"{os.cpu_count()} cores, Python {platform.python_version()}, "
        f"numpy {_version('numpy')}, rosbags {_version('rosbags')}"
    )


def _version(mod: str) -> str:
    try:
        from importlib.metadata import version

        return version(mod)
    except Exception:  # noqa: BLE001
        return "?"


def us(x: float) -> str:
    return f"{x * 1e6:.3g} us"


def status(met: Optional[bool], why: str = "") -> str:
    if met is None:
        return "recorded" + (f": {why}" if why else "")
    return "met" if met else "not met" + (f": {why}" if why else "")


def cli(argv: Sequence[str]) -> int:
    """Run ``lpv-sysid argv`` in this process (the console script's code path)."""
    from lpv_sysid.cli.main import main

    return main(list(argv))


def repo_root() -> Path:
    return Path(__file__).resolve().parent.parent


def python() -> str:
    return sys.executable
