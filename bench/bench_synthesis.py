"""Lemma 1 synthesis time vs number of uncertainty vertices (seed 0 Sec. VI; issue 5 target).

12-state, 4-input quadrotor-like polytope (lpv_sysid.synthesis.example_models), 8 scheduling
vertices x M uncertainty vertices, gamma = 1 feasibility, R/Q of seed 0 Eqs. (27)-(28) with
Eq. (32) magnitudes and T = 100 s. Prints problem size, canonicalisation and solver time, the
numpy-certified gamma and the worst independent H-inf norm over the vertices.

    .venv/bin/python -m bench.bench_synthesis [--solvers CLARABEL SCS] [--M 1 2 4 8 16]
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def run_case(M: int, solver: str, fallback=None, scale: bool = True) -> dict:
    from lpv_sysid.synthesis.example_models import quadrotor_like_polytope
    from lpv_sysid.synthesis.hinf_lmi import (HinfOptions, excitation_R, output_Q, performance_matrix,
                                              solve_lemma1)
    from lpv_sysid.synthesis.hinf_norm import hinf_norm

    p = int(round(np.log2(M)))
    model = quadrotor_like_polytope(p)
    R = excitation_R([0.1] * 4, 100.0)
    Q = output_Q([5.0] * 3, 100.0)
    C = performance_matrix(Q, 12, (2, 3, 4))
    t0 = time.perf_counter()
    res = solve_lemma1(model, R, C, HinfOptions(gamma=1.0, solver=solver, fallback=fallback, scale=scale))
    wall = time.perf_counter() - t0
    worst = 0.0
    for i, lst in enumerate(model.systems):
        for A, B in lst:
            worst = max(worst, hinf_norm(A + B @ res.K[i], B @ R, C).value)
    return dict(M=M, solver=res.solver, status=res.status, vars=res.size.scalar_variables,
                blocks=res.size.lmi_blocks, dim=res.size.lmi_total_dim, cons=res.size.scalar_constraints,
                compile=res.compile_time, solve=res.solve_time, wall=wall, gamma_cert=res.gamma_certified,
                margin=res.min_margin, worst_hinf=worst)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--solvers", nargs="+", default=["CLARABEL", "SCS"])
    ap.add_argument("--M", nargs="+", type=int, default=[1, 2, 4, 8, 16])
    ap.add_argument("--no-scale", action="store_true", help="disable the similarity scaling")
    ap.add_argument("--max-wall", type=float, default=10.0, help="skip larger M once a case exceeds this (s)")
    args = ap.parse_args(argv)
    print(f"{'solver':<9} {'M':>3} {'vars':>7} {'blocks':>6} {'dim':>6} {'constr':>7} {'compile_s':>9} "
          f"{'solve_s':>8} {'wall_s':>7} {'status':<19} {'gamma_cert':>10} {'worst_hinf':>10}")
    for solver in args.solvers:
        for M in args.M:
            try:
                r = run_case(M, solver, scale=not args.no_scale)
            except Exception as exc:  # report and go on (e.g. no certified solution without scaling)
                print(f"{solver:<9} {M:>3} failed: {str(exc)[:160]}", flush=True)
                continue
            print(f"{r['solver']:<9} {M:>3} {r['vars']:>7} {r['blocks']:>6} {r['dim']:>6} {r['cons']:>7} "
                  f"{r['compile']:>9.2f} {r['solve']:>8.2f} {r['wall']:>7.2f} {r['status']:<19} "
                  f"{r['gamma_cert']:>10.4f} {r['worst_hinf']:>10.4f}", flush=True)
            if r["wall"] > args.max_wall:
                break


if __name__ == "__main__":
    main()
