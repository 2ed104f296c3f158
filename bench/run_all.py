"""Run every benchmark module in bench/ (``make bench``), then assemble BENCHMARKS.md.

Each ``bench/bench_<topic>.py`` has a ``main()``; the issue-15 modules write their page and
summary rows to bench/results/ (bench/harness.py), which ``bench.assemble`` turns into
BENCHMARKS.md. ``python -m bench.run_all bench_bag bench_phase2`` runs only those.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import bench


def main(argv=None) -> int:
    only = list(sys.argv[1:] if argv is None else argv)
    names = sorted(
        m.name for m in pkgutil.iter_modules(bench.__path__) if m.name.startswith("bench_")
    )
    if only:
        names = [n for n in names if n in only]
    failed = []
    for name in names:
        module = importlib.import_module(f"bench.{name}")
        entry = getattr(module, "main", None)
        if entry is None:
            continue
        sys.stdout.write(f"\n=== {name}\n")
        sys.stdout.flush()
        try:
            entry([]) if "argv" in entry.__code__.co_varnames[
                : entry.__code__.co_argcount
            ] else entry()
        except Exception as exc:  # report and continue with the other benchmarks
            failed.append(name)
            sys.stdout.write(f"{name} failed: {exc!r}\n")
    from bench import assemble

    assemble.main()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
