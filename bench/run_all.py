"""Run every benchmark module in bench/ (``make bench``).

Each ``bench/bench_<topic>.py`` has a ``main()`` that prints its own medians; results
that are kept live in BENCHMARKS.md together with the command that produced them.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import bench


def main() -> int:
    names = sorted(m.name for m in pkgutil.iter_modules(bench.__path__) if m.name.startswith("bench_"))
    failed = []
    for name in names:
        module = importlib.import_module(f"bench.{name}")
        entry = getattr(module, "main", None)
        if entry is None:
            continue
        sys.stdout.write(f"\n=== {name}\n")
        sys.stdout.flush()
        try:
            entry()
        except Exception as exc:  # report and continue with the other benchmarks
            failed.append(name)
            sys.stdout.write(f"{name} failed: {exc!r}\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
