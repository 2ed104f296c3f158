"""Benchmarks of issue 3 (excitation signals).

Run: ``.venv/bin/python -m bench.bench_signals``. Prints medians of

* the design time of the shipped phase-2 set (7 channels, 100 s, 50 Hz) and phase-1 set;
* RPF per channel, optimised and Schroeder-only, with the harmonic count;
* max |corr| between channels over one period;
* one ``ExcitationCore.sample`` lookup (median over batches, per call).
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from lpv_sysid.signals.excitation import ExcitationCore
from lpv_sysid.signals.metrics import max_cross_correlation
from lpv_sysid.signals.multisine import design, load_config

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _design_times(path: str, repeats: int):
    cfg = load_config(path)
    times, sig = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        sig = design(cfg)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), min(times), sig


def _lookup_us(sig, batches: int = 50, per_batch: int = 2000) -> tuple[float, float]:
    core = ExcitationCore.phase2(sig.t, sig.u, sig.names, start_time=0.0, ramp=2.0)
    ts = np.linspace(0.0, core.end_time, batches * per_batch).tolist()
    per_call = []
    k = 0
    sample = core.sample
    for _ in range(batches):
        chunk = ts[k : k + per_batch]
        k += per_batch
        t0 = time.perf_counter()
        for t in chunk:
            sample(t)
        per_call.append((time.perf_counter() - t0) / per_batch * 1e6)
    return statistics.median(per_call), min(per_call)


def main() -> None:
    print(f"load average before: {os.getloadavg()[0]:.2f} (2 cores shared)")
    for name, repeats in (("signals_phase2.yaml", 5), ("signals_phase1.yaml", 5)):
        med, best, sig = _design_times(os.path.join(ROOT, "config", name), repeats)
        print(
            f"\n{name}: design median {med:.3f} s (min {best:.3f} s) over {repeats} runs, "
            f"{len(sig.names)} channels, N = {sig.t.size}"
        )
        print(f"  max |corr| off-diagonal over one period: {max_cross_correlation(sig.u):.2e}")
        print("  channel   harmonics   RPF opt   RPF Schroeder")
        for j, n in enumerate(sig.names):
            print(
                f"  {n:8s}  {sig.harmonics[j].size:9d}   {sig.rpf[j]:.4f}    "
                f"{sig.rpf_schroeder[j]:.4f}"
            )
        if name == "signals_phase2.yaml":
            med_us, best_us = _lookup_us(sig)
            print(
                f"  ExcitationCore.sample: median {med_us:.2f} us/call (min batch {best_us:.2f} "
                "us), "
                "50 batches x 2000 calls"
            )
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
