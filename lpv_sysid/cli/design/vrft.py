"""`lpv-sysid vrft`: data-driven controller tuning by MIMO Virtual Reference Feedback Tuning (seed
1).

    lpv-sysid vrft --data FILE.npz --config config/vrft_example.yaml --out controller.yaml
    lpv-sysid vrft --example table5.3 [--noise 0.05] [--out controller.yaml]
    lpv-sysid vrft --example lv100 [--n 10000]

FILE.npz holds ``t`` (N,), ``u`` (N, n_u), ``y`` (N, n_y); optionally ``y2`` (second experiment,
method iv), ``instrument`` (N, q: external excitation for EIV on closed-loop data) and, with an
``outer`` config section, ``y_outer`` (cascade, seed 1 Sec. 3.3.4). Prints the identified
parameters and the virtual-reference cost J_VR (Eq. 3.13); for the built-in examples also the
model-reference cost ||M - T||_2^2 (Eq. 3.4) with the true plant and the thesis' table.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.files import save_yaml
from lpv_sysid.vrft import LV100_CONFIG, TABLE53_CONFIG, TuneResult, load_data, tune

COMMAND = "vrft"
HELP = "tune a (MIMO, optionally cascaded) controller from I/O data by VRFT (seed 1 Sec. 3.3)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", help="npz with t, u, y (optional y2, instrument, y_outer)")
    parser.add_argument("--config", help="VRFT YAML (see config/vrft_example.yaml)")
    parser.add_argument("--out", help="controller YAML to write")
    parser.add_argument(
        "--example",
        choices=["table5.3", "lv100"],
        help="generate the thesis benchmark data (seed 1 Table 5.3 / Tables 5.1-5.2) and run it",
    )
    parser.add_argument(
        "--noise",
        type=float,
        default=0.0,
        help="table5.3: output noise std (then method eiv is used unless --config says otherwise)",
    )
    parser.add_argument("--n", type=int, default=None, help="example: number of samples")
    parser.add_argument("--seed", type=int, default=0, help="example: random seed")
    parser.add_argument(
        "--runs",
        type=int,
        default=0,
        help="lv100: Table 5.2 statistics over this many noise realisations (same PRBS)",
    )
    parser.add_argument(
        "--eiv-weight",
        choices=["identity", "residual"],
        default="identity",
        help="lv100 --runs: EIV weight W of Eq. (3.31) (default identity)",
    )


def _read_yaml(path: str) -> dict:
    from lpv_sysid.io.files import read_yaml

    p = Path(path)
    if not os.path.lexists(p):
        raise ConfigError(f"config file not found: {p}")
    d = read_yaml(p)
    if not isinstance(d, dict):
        raise ConfigError(f"{p}: expected a mapping at the top level")
    return d


def _fmt_matrix(name: str, K: np.ndarray) -> str:
    rows = ["  ".join(f"{v:+.4f}" for v in r) for r in np.atleast_2d(K)]
    return f"  {name} = [" + "; ".join(rows) + "]"


def _lines(out: TuneResult) -> list[str]:
    return [line for title, res in out.loops.items() for line in _report(title, res)]


def _report(title: str, res) -> list[str]:
    lines = [
        f"{title}: method {res.method}, N = {res.n_samples}, cond = {res.condition:.3g}, "
        f"J_VR (Eq. 3.13) = {res.J_vr:.6g}"
    ]
    for nm, K in zip(res.cls.names, res.K):
        lines.append(_fmt_matrix(nm, K))
    return lines


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.vrft import VrftConfig

    if args.example is None and (args.data is None or args.config is None):
        raise ConfigError(
            "give --data FILE.npz and --config FILE.yaml, or --example table5.3|lv100"
        )
    if args.example is not None and args.data is not None:
        raise ConfigError("--example generates its own data; do not combine it with --data")
    if args.example is not None:
        if args.n is not None and args.n < 50:
            raise ConfigError(f"--n {args.n}: the examples need at least 50 samples")
        if not np.isfinite(args.noise) or args.noise < 0:
            raise ConfigError(f"--noise {args.noise}: must be a finite standard deviation >= 0")
        if args.runs:
            return _run_statistics(args)
        return _run_example(args)

    cfg = VrftConfig.from_dict(_read_yaml(args.config))
    out = tune(cfg, load_data(args.data), str(args.data))
    for line in _lines(out):
        print(line)
    if args.out:
        save_yaml(out.doc, args.out)
        print(f"wrote {args.out}")
    return 0


def _run_example(args: argparse.Namespace) -> int:
    from lpv_sysid.vrft import VrftConfig, model_reference_h2
    from lpv_sysid.vrft import examples as ex

    if args.example == "table5.3":
        base = dict(TABLE53_CONFIG)
        if args.noise > 0:
            base["method"] = "eiv"
        t, u, y, _ = ex.table53_data(
            args.n or (2000 if args.noise > 0 else 500), args.seed, args.noise
        )
        G, M = ex.table53_plant_ss(), ex.table53_model()
    else:
        base = dict(LV100_CONFIG)
        t, u, y, _ = ex.lv100_data(args.n or 10000, args.seed, closed_loop=False)
        G, M = ex.lv100_plant_ss(), ex.lv100_model()
    cfg = VrftConfig.from_dict(_read_yaml(args.config) if args.config else base)
    out = tune(cfg, {"t": t, "u": u, "y": y}, f"example {args.example}")
    res = next(iter(out.loops.values()))
    if args.example == "table5.3":
        a, b = ex.table53_ideal_pi()
        print(
            f"seed 1 Table 5.3 example: G of Eq. (5.4), M = 0.1/(z-0.9) I, N = {t.size}, noise "
            f"std {args.noise}"
        )
    else:
        print(
            f"seed 1 LV100 (Eq. 5.1, Tustin 0.1 s), open-loop PRBS, noise var 0.0025, N = {t.size}"
        )
    for line in _lines(out):
        print(line)
    if cfg.outer is None and hasattr(res, "K") and res.cls.kind == "pid" and len(res.K) == 2:
        Kp, Ki = res.K
        A_, B_ = Kp + Ki * res.cls.Ts, Kp
        print(
            "  C_ij = (a z - b)/(z - 1):  a = "
            + np.array2string(A_, precision=4).replace("\n", "")
            + "  b = "
            + np.array2string(B_, precision=4).replace("\n", "")
        )
        if args.example == "table5.3":
            print(
                "  Table 5.3 MIMO (published): a = "
                + np.array2string(ex.TABLE53_MIMO_A).replace("\n", "")
                + "  b = "
                + np.array2string(ex.TABLE53_MIMO_B).replace("\n", "")
            )
            dev = max(np.abs(A_ - ex.TABLE53_MIMO_A).max(), np.abs(B_ - ex.TABLE53_MIMO_B).max())
            print(f"  max |a - a_pub|, |b - b_pub| = {dev:.2e}")
        else:
            kp = np.array([[ex.LV100_T52_KP[(i, j)][0] for j in range(2)] for i in range(2)])
            ki = np.array([[ex.LV100_T52_KI[(i, j)][0] for j in range(2)] for i in range(2)])
            print(
                "  Table 5.2 (N=1e4, magnitudes; Table 5.1 gives (2,2) negative): Kp = "
                + np.array2string(kp).replace("\n", "")
                + "  Ki = "
                + np.array2string(ki).replace("\n", "")
            )
        jmr = model_reference_h2(res, G, M, n_imp=2000)
        print(f"  model-reference cost ||M - T||_2^2 (Eq. 3.4, true plant) = {jmr:.6g}")
        out.doc["controller"]["J_mr_true_plant"] = float(jmr)
    if args.out:
        save_yaml(out.doc, args.out)
        print(f"wrote {args.out}")
    return 0


def _run_statistics(args: argparse.Namespace) -> int:
    """Seed 1 Table 5.2: mean, std and std/|mean| of Kp, Ki over noise realisations."""
    from lpv_sysid.vrft import examples as ex

    if args.example != "lv100":
        raise ConfigError("--runs is only available with --example lv100 (Table 5.2)")
    if args.runs < 2:
        raise ConfigError(
            f"--runs {args.runs}: need at least 2 realisations for a standard deviation"
        )
    n = args.n or 1000
    mkp, skp, mki, ski = ex.lv100_statistics(
        n, args.runs, seed=args.seed, eiv_weight=args.eiv_weight
    )
    print(
        f"seed 1 Table 5.2 protocol: LV100 open loop, one PRBS (seed {args.seed}), {args.runs} "
        "noise "
        f"realisations (var 0.0025), N = {n}, EIV l = 20, W = {args.eiv_weight}"
    )
    print(
        f"{'':4}{'entry':7}{'theta':>10}{'sigma':>9}{'s/|th|':>8}   | thesis theta  sigma  (N=1e3 "
        "/ 1e4)"
    )
    t3 = ex.LV100_T52_N1E3
    t4 = {"Kp": ex.LV100_T52_KP, "Ki": ex.LV100_T52_KI}
    rows = []
    for name, m, sd in (("Kp", mkp, skp), ("Ki", mki, ski)):
        for ij in ((0, 0), (1, 0), (0, 1), (1, 1)):
            th, sg = m[ij], sd[ij]
            line = (
                f"{name:4}({ij[0] + 1},{ij[1] + 1})  "
                f"{th:10.3f}{sg:9.3f}{sg / max(abs(th), 1e-12):8.3f}   | "
                f"{t3[name][ij][0]:7.3f} {t3[name][ij][1]:6.3f} / {t4[name][ij][0]:7.3f} "
                f"{t4[name][ij][1]:6.3f}"
            )
            print(line)
            rows.append(
                {"param": f"{name}({ij[0] + 1},{ij[1] + 1})", "mean": float(th), "std": float(sg)}
            )
    if args.out:
        save_yaml(
            {
                "format": "lpv_sysid/vrft_statistics@1",
                "example": "lv100",
                "n": n,
                "runs": args.runs,
                "rows": rows,
            },
            args.out,
        )
        print(f"wrote {args.out}")
    return 0
