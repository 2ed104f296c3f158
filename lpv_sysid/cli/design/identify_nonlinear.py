"""`lpv-sysid identify-nonlinear`: lumped parameters K of seed 0 Eq. (6) from flight bags.

    lpv-sysid identify-nonlinear --bags DIR --out nonlinear_model.yaml [--refine]
    lpv-sysid identify-nonlinear --structure px4 --bags DIR [DIR ...] --out M.yaml \
        [--validate DIR ...] [--plot-validation PNG] [--sih NAME=VALUE ...]

``--structure px4`` (PX4 bags without ESC telemetry: ``state``, ``imu``, estimated
``rotor_speeds``) fits the documented PX4 variant of Eq. (6)
(``ident.nonlinear.px4_model``), predicts the flights of ``--validate`` (R^2, TIC per axis)
and, with ``--sih``, compares the physical quantities with PX4 SIH's parameters.

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
        nargs="+",
        help="rosbag2 directories, or directories holding several (px4: several flights)",
    )
    parser.add_argument(
        "--structure",
        choices=("eq6", "px4"),
        default="eq6",
        help="eq6: seed 0 Eq. (6) with rotor speeds; px4: the PX4 variant (motor outputs, "
        "specific force, angular acceleration, motor lag; ident.nonlinear.px4_model)",
    )
    parser.add_argument("--intercept", action="store_true", help="px4: a constant per axis")
    parser.add_argument(
        "--validate",
        type=Path,
        nargs="+",
        default=[],
        help="px4: bags of flights not used in the fit, predicted by the model",
    )
    parser.add_argument(
        "--plot-validation", type=Path, default=None, help="px4: prediction vs data figure"
    )
    parser.add_argument(
        "--sih",
        action="append",
        default=None,
        metavar="NAME=VALUE",
        help="px4: compare with PX4 SIH (its defaults, overridden by each NAME=VALUE; "
        "'--sih default' for the defaults)",
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


def _bag_dirs(paths) -> list[Path]:
    from lpv_sysid.ident import dataprep as dp

    out: list[Path] = []
    for p in paths:
        out.extend([p] if (p / "metadata.yaml").exists() else dp.find_bags(p))
    return out


def _sih_params(items) -> dict[str, float]:
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.ident.nonlinear import SIH_DEFAULTS

    out = {}
    for it in items:
        if it == "default":
            continue
        name, sep, val = it.partition("=")
        if not sep or name not in SIH_DEFAULTS:
            raise ConfigError(
                f"--sih {it!r}: expected NAME=VALUE with NAME in {list(SIH_DEFAULTS)}"
            )
        try:
            out[name] = float(val)
        except ValueError:
            raise ConfigError(f"--sih {it!r}: value is not a number") from None
    return out


def plot_prediction(pred, path: Path, title: str) -> Path:
    """Measured against predicted specific forces and angular accelerations, per axis."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from lpv_sysid.ident.nonlinear import PX4_AXES, PX4_OUTPUTS

    fig = Figure(figsize=(9, 10))
    FigureCanvasAgg(fig)
    axs = list(fig.subplots(6, 1, sharex=True, squeeze=False)[:, 0])
    step = float(np.median(np.diff(pred.t))) if pred.t.size > 1 else 1.0
    x = np.arange(pred.t.size) * step  # records stacked end to end
    for ax, a in zip(axs, PX4_AXES):
        name, unit = PX4_OUTPUTS[a]
        ax.plot(x, pred.measured[a], "k-", lw=0.6, label="measured")
        ax.plot(x, pred.predicted[a], "r-", lw=0.6, label="model")
        ax.set_ylabel(f"{name}\n[{unit}]", fontsize=8)
        ax.set_title(f"R^2 {pred.r2[a]:.3f}  TIC {pred.tic[a]:.3f}", fontsize=8, loc="right")
    axs[0].legend(loc="upper left", fontsize=7)
    axs[-1].set_xlabel("t [s] (records stacked)")
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=100)
    return path


def run_px4(args: argparse.Namespace, params, cfg) -> int:
    """``--structure px4``: fit, validate, compare (``ident.nonlinear.px4_model``)."""
    from lpv_sysid.ident import dataprep as dp
    from lpv_sysid.io.files import save_yaml
    from lpv_sysid.ident import nonlinear as nl

    def records(paths):
        recs = []
        for b in _bag_dirs(paths):
            r = dp.px4_record(b, params, cfg.sample_rate, cfg.derivatives, cfg.edge)
            print(f"{r.name}: {r.t.size} samples, {r.t[-1] - r.t[0]:.1f} s")
            recs.append(r)
        return recs

    fit = records(args.bags)
    model = nl.identify_px4(fit, intercept=args.intercept, max_lag=cfg.max_lag)
    print()
    print("PX4 variant of seed 0 Eq. (6) (ident.nonlinear.px4_model), equation error")
    print(
        f"motor lag tau = {model.tau:.4f} s, std {model.tau_std:.4f} s "
        f"(statistical {model.tau_std_statistical:.4f}, "
        f"output timing +-{model.timing_s / 2:.3f} s)"
    )
    print(f"{'axis':>4} {'K':>6} {'regressor':>10} {'estimate':>12} {'std':>10} {'95% CI':>24}")
    for a in model.axes.values():
        for n, lb, k, sd in zip(a.names, a.labels, a.K, a.std):
            print(
                f"{a.axis:>4} {n:>6} {lb:>10} {k:12.5g} {sd:10.3g}   "
                f"[{k - 1.96 * sd:10.4g}, {k + 1.96 * sd:10.4g}]"
            )
    print()
    print("Regressor correlation (seed 0 Fig. 10) and R^2 per axis")
    for fit_axis in model.axes.values():
        print(format_correlation(fit_axis))
    doc = model.to_dict()
    doc["bags"] = [r.name for r in fit]
    pq = nl.physical_quantities(model)
    doc["physical"] = {k: {"value": float(v), "std": float(s)} for k, (v, s) in pq.items()}
    if args.validate:
        val = records(args.validate)
        pred = nl.predict(model, val)
        print()
        print("Prediction of the validation flight(s) (model of the fit flights)")
        print(f"{'output':>8} {'R^2':>8} {'TIC':>8}")
        for ax in nl.PX4_AXES:
            print(f"{nl.PX4_OUTPUTS[ax][0]:>8} {pred.r2[ax]:8.3f} {pred.tic[ax]:8.3f}")
        doc["validation"] = {
            "bags": [r.name for r in val],
            "r2": {nl.PX4_OUTPUTS[a][0]: float(pred.r2[a]) for a in nl.PX4_AXES},
            "tic": {nl.PX4_OUTPUTS[a][0]: float(pred.tic[a]) for a in nl.PX4_AXES},
        }
        if args.plot_validation is not None:
            plot_prediction(
                pred, args.plot_validation, "PX4 variant of Eq. (6): validation flight"
            )
            print(f"wrote {args.plot_validation}")
    if args.sih is not None:
        truth = nl.sih_truth(_sih_params(args.sih))
        print()
        print("Identified physical quantities against PX4 SIH (3-sigma intervals)")
        print(
            f"{'quantity':>14} {'identified':>11} {'std':>9} {'SIH':>9} "
            f"{'(SIH-id)/std':>13}  SIH expression"
        )
        rows = {}
        for k, (v, sd) in pq.items():
            z = (truth[k] - v) / sd if sd > 0 else float("inf")
            print(f"{k:>14} {v:11.4g} {sd:9.3g} {truth[k]:9.4g} {z:13.2f}  {nl.PHYSICAL[k][2]}")
            rows[k] = {
                "identified": float(v),
                "std": float(sd),
                "sih": float(truth[k]),
                "z": float(z),
            }
        doc["sih_comparison"] = rows
    save_yaml(doc, args.out, "--out")  # atomic; names --out and the path on failure
    print(f"\nwrote {args.out}")
    return 0


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from lpv_sysid.cli.design.identify import load_config
    from lpv_sysid.errors import BagError, ConfigError
    from lpv_sysid.io.files import save_yaml
    from lpv_sysid.ident import dataprep as dp
    from lpv_sysid.ident import nonlinear as nl
    from lpv_sysid.models.quadrotor import K_NAMES

    params = _params(args.quadrotor)
    cfg = load_config(args.config)
    if args.structure == "px4":
        return run_px4(args, params, cfg)
    if args.validate or args.sih is not None or args.plot_validation or args.intercept:
        raise ConfigError("--validate, --plot-validation, --sih, --intercept need --structure px4")
    if len(args.bags) != 1:
        raise ConfigError("--structure eq6 takes one --bags directory")
    args.bags = args.bags[0]
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
    save_yaml(doc, args.out, "--out")  # atomic; names --out and the path on failure
    print(f"\nwrote {args.out}")
    if args.plot is not None:
        print(f"wrote {plot_correlation(res, args.plot)}")
    return 0
