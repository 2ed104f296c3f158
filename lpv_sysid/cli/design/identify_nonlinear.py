"""`lpv-sysid identify-nonlinear`: lumped parameters K of seed 0 Eq. (6) from flight bags.

    lpv-sysid identify-nonlinear --bags DIR --out nonlinear_model.yaml [--refine]

Every rosbag2 under DIR (phase-2 data, or any flight with ``state`` and ``rotor_speeds``)
is resampled (``ident.dataprep``), differentiated (global Fourier) and stacked; Eq. (6) is
solved per axis by least squares (``ident.nonlinear.regression``: estimates, standard
errors, R^2, regressor correlation = seed 0 Fig. 10) and, with ``--refine``, refined by
short-segment output-error NLS (seed 2 Sec. 4).
"""

from __future__ import annotations

import argparse
from pathlib import Path

COMMAND = "identify-nonlinear"
HELP = "identify the nonlinear aerodynamic model (seed 0 Eq. 6) from flight bags"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bags",
        required=True,
        type=Path,
        help="a rosbag2 directory, or a directory holding several",
    )
    parser.add_argument("--out", required=True, type=Path, help="YAML file to write")
    parser.add_argument(
        "--quadrotor",
        type=Path,
        default=None,
        help="config/quadrotor.yaml: mass, inertia, arm length, J_z (known constants)",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="identification YAML (derivative settings, sample rate)",
    )
    parser.add_argument(
        "--refine", action="store_true", help="output-error refinement (seed 2 Sec. 4)"
    )
    parser.add_argument(
        "--segment", type=float, default=2.0, help="output-error segment length, s"
    )
    parser.add_argument("--max-segments", type=int, default=40, help="output-error segments used")
    parser.add_argument(
        "--max-nfev", type=int, default=60, help="output-error function evaluations"
    )
    parser.add_argument(
        "--fix",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="hold a lumped parameter at a value (repeatable)",
    )
    parser.add_argument(
        "--plot", type=Path, default=None, help="regressor-correlation figure (Fig. 10)"
    )


def _params(path: Path | None):
    from lpv_sysid.cli.design.identify import quadrotor_section
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.models.quadrotor import QuadrotorParams

    if path is None:
        return QuadrotorParams()
    q = quadrotor_section(path)
    try:
        return QuadrotorParams.from_dict(q)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def _fixed(items) -> dict[str, float]:
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.models.quadrotor import K_NAMES

    out = {}
    for it in items:
        name, sep, val = it.partition("=")
        if not sep or name not in K_NAMES:
            raise ConfigError(f"--fix {it!r}: expected NAME=VALUE with NAME in {list(K_NAMES)}")
        try:
            out[name] = float(val)
        except ValueError:
            raise ConfigError(f"--fix {it!r}: value is not a number") from None
    return out


def format_correlation(axis) -> str:
    """Lower-triangular correlation matrix of one axis, as seed 0 Fig. 10."""
    lines = [f"axis {axis.axis}: R^2 = {axis.r2:.4f}"]
    for i, lab in enumerate(axis.labels):
        cells = " ".join(f"{axis.correlation[i, j]:+.3f}" for j in range(i))
        lines.append(f"  {cells} {'' if i == 0 else ' '}{lab}")
    return "\n".join(lines)


def plot_correlation(result, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    axes = list(result.axes.values())
    fig, axs = plt.subplots(2, 3, figsize=(13, 8))
    for ax, a in zip(axs.ravel(), axes):
        c = np.where(np.isfinite(a.correlation), a.correlation, 0.0)
        im = ax.imshow(np.abs(c), vmin=0, vmax=1, cmap="viridis")
        ax.set_xticks(range(len(a.labels)), a.labels, rotation=60, ha="right", fontsize=7)
        ax.set_yticks(range(len(a.labels)), a.labels, fontsize=7)
        ax.set_title(f"{a.axis} (R^2 {a.r2:.3f})")
        for i in range(c.shape[0]):
            for j in range(c.shape[1]):
                ax.text(j, i, f"{c[i, j]:+.2f}", ha="center", va="center", fontsize=6, color="w")
    fig.colorbar(im, ax=axs.ravel().tolist(), shrink=0.6, label="|correlation|")
    fig.suptitle("Nonlinear model regressor correlation (seed 0 Fig. 10)")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def run(args: argparse.Namespace) -> int:
    import numpy as np
    import yaml

    from lpv_sysid.cli.design.identify import load_config
    from lpv_sysid.errors import BagError, ConfigError
    from lpv_sysid.ident import dataprep as dp
    from lpv_sysid.ident import nonlinear as nl
    from lpv_sysid.models.quadrotor import K_NAMES

    params = _params(args.quadrotor)
    cfg = load_config(args.config)
    fixed = _fixed(args.fix)
    if args.segment <= 0 or args.max_segments < 1 or args.max_nfev < 1:
        raise ConfigError("--segment, --max-segments and --max-nfev must be positive")
    bags = [args.bags] if (args.bags / "metadata.yaml").exists() else dp.find_bags(args.bags)
    pieces = []
    for bag in bags:
        g = dp.resample(dp.streams_from_bag(bag), cfg.sample_rate)
        st = g["state"]
        data, smoother, keep = nl.flight_data(
            g["t"], st[:, 0:3], st[:, 3:6], st[:, 6:9], g["Omega"], cfg.derivatives, cfg.edge
        )
        pieces.append((bag, data, smoother, keep))
        print(f"{bag.name}: {g['t'].size} samples, {g['t'][-1] - g['t'][0]:.1f} s")
    if not pieces:
        raise BagError(f"{args.bags}: no usable bags")
    # stack the records: regression per bag is combined by concatenating the filtered rows
    res = nl.regression_stacked(
        [(d, sm, kp) for _, d, sm, kp in pieces], params, cfg.max_lag, fixed
    )
    print()
    print("Lumped parameters of seed 0 Eq. (6), equation-error regression")
    print(f"{'K':>12} {'estimate':>13} {'std':>11}")
    for k in K_NAMES:
        print(f"{k:>12} {res.K[k]:13.5e} {res.std[k]:11.3e}")
    print()
    print("Regressor correlation (seed 0 Fig. 10)")
    for a in res.axes.values():
        print(format_correlation(a))
    doc = {
        "format": "lpv_sysid/nonlinear_model@1",
        "model": "seed 0 Eq. (6)",
        "bags": [str(b) for b, *_ in pieces],
        "K": {k: float(res.K[k]) for k in K_NAMES},
        "std": {k: float(res.std[k]) for k in K_NAMES},
        "fixed": fixed,
        "axes": {
            a.axis: {
                "r2": float(a.r2),
                "regressors": list(a.labels),
                "parameters": list(a.names),
                "correlation": np.where(np.isfinite(a.correlation), a.correlation, 0.0).tolist(),
            }
            for a in res.axes.values()
        },
    }
    if args.refine:
        bag, data, sm_sel, _ = max(pieces, key=lambda p: p[1].t.size)
        free = tuple(k for k in K_NAMES if k not in fixed)
        oe = nl.output_error(
            data,
            params,
            res.K,
            nl.OutputErrorConfig(args.segment, args.max_segments, args.max_nfev, free),
            res.std,
            sm_sel,
        )
        print()
        print(f"Output-error refinement on {bag.name} (seed 2 Sec. 4): cost {oe.cost:.4g}")
        print(f"{'K':>12} {'regression':>13} {'refined':>13} {'std':>11}")
        for k in free:
            print(
                f"{k:>12} {res.K[k]:13.5e} {oe.K[k]:13.5e} "
                f"{oe.refined_std.get(k, float('nan')):11.3e}"
            )
        doc["refined"] = {
            "method": "output error, short segments (seed 2 Sec. 4)",
            "cost": oe.cost,
            "segment_s": args.segment,
            "K": {k: float(oe.K[k]) for k in K_NAMES},
            "std": {k: float(v) for k, v in oe.refined_std.items()},
        }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    try:
        args.out.write_text(yaml.safe_dump(doc, sort_keys=False))
    except OSError as exc:
        raise ConfigError(f"--out {args.out}: cannot write ({exc.strerror})") from None
    print(f"\nwrote {args.out}")
    if args.plot is not None:
        print(f"wrote {plot_correlation(res, args.plot)}")
    return 0
