"""`lpv-sysid verify`: re-check a gains certificate without trusting the LMI solver.

    lpv-sysid verify --gains gains.yaml --models vertex_models.yaml

Frozen-parameter closed-loop H-infinity norms (Hamiltonian bisection) at every vertex and
uncertainty corner and at random interior scheduling points, closed-loop eigenvalues in the
promised region, the Eq. (30) LMIs re-evaluated with numpy from the certificate sidecar, hashes,
names and box. Prints a table; exit status 1 when any check fails, 2 on unreadable input.
"""

from __future__ import annotations

import argparse

COMMAND = "verify"
HELP = "independently re-check gains.yaml against vertex_models.yaml (H-inf norms, poles, LMIs)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--gains", required=True, help="gains.yaml (synthesize)")
    parser.add_argument("--models", required=True, help="vertex_models.yaml the gains were synthesised for")
    parser.add_argument("--random", type=int, default=20, help="random interior scheduling points (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the interior points")
    parser.add_argument("--all-rows", action="store_true", help="print every check, not only failures + worst")


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.synthesis.verify import verify_files

    rep = verify_files(args.gains, args.models, n_random=args.random, seed=args.seed)
    print(rep.table(max_rows=10 ** 6) if not args.all_rows else _all(rep))
    print("PASS" if rep.passed else "FAIL")
    return 0 if rep.passed else 1


def _all(rep) -> str:
    lines = [f"{r.check:<14} {r.where:<28} {r.value:>12.6g} {r.limit:>12.6g}  {'ok' if r.ok else 'FAIL'} {r.note}"
             for r in rep.rows]
    return "\n".join(lines)
