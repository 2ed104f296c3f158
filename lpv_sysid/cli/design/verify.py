"""`lpv-sysid verify`: re-check a gains certificate without trusting the LMI solver.

    lpv-sysid verify --gains gains.yaml --models vertex_models.yaml [--full-box 200]
        [--strict-full-box] [--out verification.yaml]

Frozen-parameter closed-loop H-infinity norms (Hamiltonian bisection) at every vertex and
uncertainty corner and at random interior scheduling points, closed-loop eigenvalues in the
promised region, the Eq. (30) LMIs re-evaluated with numpy from the certificate sidecar, hashes,
names and box. For a full-box certificate (``certified_set.kind: full_identified_box``,
docs/certificate.md): the certified box against the models file read independently, the robust
LMI in its uncompressed form, the scaled small-gain (KYP) condition at every vertex, the runtime's
systems inside the box, and the scheduling claim (frozen / arbitrary / rate-bounded v_d).

``--full-box N`` (default 200, 0 disables) adds an *empirical* Monte Carlo check against the FULL
identified uncertainty (every identified element in its Eq. 22 interval;
:mod:`lpv_sysid.synthesis.verify.montecarlo`). For a reduced-polytope certificate, which does not
claim that set, a miss is reported as WARN and does not change the exit status unless
``--strict-full-box`` is given; for a full-box certificate it is a cross-check of the claim and a
miss fails (with the file's own k and intervals).

Prints a table and writes ``verification.yaml`` next to the gains file (``--out`` elsewhere;
:mod:`lpv_sysid.synthesis.verify.report`: pass/fail per check, gamma, LMI margins, eigenvalues,
the SHA-256 of the gains and models files checked, the tool version), which ``lpv-sysid report``
reads instead of re-running the checks; also when a check fails. Exit status 1 when any
(non-advisory) check fails, 2 on unreadable input.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from lpv_sysid.parallel import BACKENDS
from lpv_sysid.synthesis.verify import VERIFY_SETTINGS

COMMAND = "verify"
HELP = (
    "independently re-check gains.yaml against vertex_models.yaml (H-inf norms, poles, LMIs, "
    "full-box MC); writes verification.yaml"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--gains", required=True, help="gains.yaml (synthesize)")
    parser.add_argument(
        "--models", required=True, help="vertex_models.yaml the gains were synthesised for"
    )
    parser.add_argument(
        "--random",
        type=int,
        default=VERIFY_SETTINGS["n_random"],
        help="random interior scheduling points (default %(default)s)",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=VERIFY_SETTINGS["seed"],
        help="seed of the interior points and of the --full-box samples (default 0)",
    )
    parser.add_argument(
        "--full-box",
        type=int,
        default=VERIFY_SETTINGS["full_box"],
        metavar="N",
        help="empirical Monte Carlo over the FULL identified uncertainty box: N scheduling "
        "points (corners, then random interior), every identified element drawn "
        "independently from [lower, upper] where the models file stores lower < upper, "
        "else nominal +/- k std (k = meta.k_sigma), plus 2 first-order worst corners per "
        "vertex; frozen closed-loop H-inf norm and spectral abscissa (default 200, 0 = off). "
        "Not claimed by the certificate: a miss prints WARN and keeps exit 0 unless "
        "--strict-full-box",
    )
    parser.add_argument(
        "--strict-full-box",
        action="store_true",
        help="make a --full-box miss (any sample unstable or above gamma) fail verify (exit 1)",
    )
    parser.add_argument(
        "--k-sigma",
        type=float,
        default=None,
        help="half-width in std of the full box (default: the models file's meta.k_sigma, else 3)",
    )
    parser.add_argument(
        "--full-box-kept",
        choices=("stored", "ksigma"),
        default="stored",
        help="intervals of the kept corner parameters: 'stored' (the widened [lower, upper] "
        "of the file, default) or 'ksigma' (nominal +/- k std, the Eq. 22 box itself)",
    )
    parser.add_argument(
        "--loop-delay",
        type=float,
        default=None,
        metavar="SECONDS",
        help="worst delay of the configured loop (input latency + 1 / state rate + 1 / "
        "command rate); FAIL when above the certificate's loop_delay.bound_s",
    )
    parser.add_argument(
        "--out",
        default=None,
        metavar="PATH",
        help="where to write the verification record (default: verification.yaml next to the "
        "gains file)",
    )
    parser.add_argument(
        "--all-rows", action="store_true", help="print every check, not only failures + worst"
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="processes judging the --full-box samples (default: every core this process may "
        "use; 1 = serial; the numbers do not depend on it)",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="process",
        help="where the --workers run: process (a local process pool, default) or dask (the "
        "active dask.distributed client, else Dask's local processes; dask must be installed)",
    )
    parser.add_argument(
        "--key",
        default=None,
        metavar="FILE",
        help="operator seal key: require and check the file's keyed seal (seal.hmac_sha256); "
        "without it only the unkeyed seal and certificate.gains_sha256 are checked",
    )


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.parallel import resolve_workers
    from lpv_sysid.io.formats import load_seal_key
    from lpv_sysid.synthesis.verify import verify_and_record

    resolve_workers(args.workers)
    if args.full_box < 0:
        raise ConfigError(f"--full-box must be >= 0, got {args.full_box}")
    t0 = time.perf_counter()
    key = load_seal_key(args.key) if args.key else None
    rep, out = verify_and_record(
        args.gains,
        args.models,
        args.out,
        seal_key=key,
        n_random=args.random,
        seed=args.seed,
        full_box=args.full_box,
        strict_full_box=args.strict_full_box,
        k_sigma=args.k_sigma,
        full_box_kept=args.full_box_kept,
        workers=args.workers,
        backend=args.backend,
        loop_delay_s=args.loop_delay,
    )
    print(
        "gains file: law matches certificate.gains_sha256, seal.sha256 matches the whole file"
        + (", keyed seal (seal.hmac_sha256) checked with the key" if key else "")
    )
    print(rep.table(max_rows=10**6) if not args.all_rows else _all(rep))
    fb = rep.full_box
    if fb is not None:
        print(_full_box_line(fb, args.strict_full_box))
    print(f"wrote {out}")
    print(f"verify took {time.perf_counter() - t0:.2f} s")
    print("PASS" if rep.passed else "FAIL")
    return 0 if rep.passed else 1


def _full_box_line(fb: Any, strict: bool) -> str:
    s = fb.summary()
    verdict = (
        ""
        if fb.passed
        else (
            " -> FAIL (--strict-full-box)"
            if strict
            else " -> WARN (not certified; --strict-full-box to fail)"
        )
    )
    return (
        f"full identified box (empirical, {s['samples']} samples, seed {s['seed']}, "
        f"k = {s['k_sigma']:g} [{s['k_sigma_source']}], {s['intervals_stored']} stored / "
        f"{s['intervals_k_std']} k*std intervals): worst norm {s['worst_norm']:.6g} vs gamma "
        f"{s['gamma']:g} at v_d {s['worst_v_d']} ({s['worst_where']}), fraction ok "
        f"{s['fraction_ok']:.3f}, all stable {s['all_stable']}{verdict}"
    )


def _all(rep: Any) -> str:
    lines = [
        f"{r.check:<14} {r.where:<28} {r.value:>12.6g} {r.limit:>12.6g}  {r.result} {r.note}"
        for r in rep.rows
    ]
    return "\n".join(lines)
