"""`lpv-sysid identify`: phase-1 bags -> vertex_models.yaml (seed 0 Sec. IV, Tables 1-3).

    lpv-sysid identify --bags DIR --config config/identification.yaml --out vertex_models.yaml
    lpv-sysid identify --plant px4-rate --bags DIR/phase1 [DIR2 ...] --out vertex_models.yaml \
        [--campaign config/campaign_chain.yaml] [--k-sigma 2]

Every rosbag2 directory under DIR is one maneuver.  Its velocity reference during the
trim segment decides what it is: a corner of the scheduling box -> a vertex model; the
box centre -> the independent validation maneuver (seed 0 Table 3, Fig. 4). The models are also
written as a MATLAB file next to it (``vertex_models.mat``: lpv_sysid/io/formats/export.py).

``--plant px4-rate``: the rate plant PX4 executes (lpv_sysid/models/rate_plant.py: thrust +
body-rate setpoints in, PX4's rate loop inside), identified from the campaign's bags that carry
PX4's ATTITUDE_TARGET on ``rate_setpoint`` -- the chain's step 2, the same code
(:func:`lpv_sysid.flight.chain.identify_rate_runs`) -- over the scheduling box of the campaign
config; its gains fly through ``phase2.launch.py design:=rate_plant`` or ``fly phase2``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

COMMAND = "identify"
HELP = "identify the uncertain vertex LTI models from phase-1 bags (seed 0 Sec. IV)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bags",
        required=True,
        type=Path,
        nargs="+",
        help="directory holding one rosbag2 per maneuver; px4-rate: one or more (the flights "
        "of a campaign that took several batteries, fly phase1 --resume)",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="identification YAML (default: built-in values = config/identification.yaml)",
    )
    parser.add_argument("--out", required=True, type=Path, help="vertex_models.yaml to write")
    parser.add_argument(
        "--plant",
        choices=("quadrotor", "px4-rate"),
        default="quadrotor",
        help="quadrotor: seed 0 virtual-actuator vertex models (default); px4-rate: the rate "
        "plant PX4 executes (bags with rate_setpoint, e.g. fly phase1 --record-rate-setpoints)",
    )
    parser.add_argument(
        "--campaign",
        type=Path,
        default=None,
        help="px4-rate: campaign config whose box the vertex models span "
        "(default config/campaign_chain.yaml)",
    )
    parser.add_argument(
        "--k-sigma",
        type=float,
        default=2.0,
        help="px4-rate: interval half-width of the identified elements in standard deviations",
    )
    parser.add_argument(
        "--plot",
        type=Path,
        default=None,
        help="validation figure (default: next to --out, <stem>_validation.png)",
    )
    parser.add_argument(
        "--quadrotor",
        type=Path,
        default=None,
        help="config/quadrotor.yaml: vehicle parameters for the known elements",
    )


def load_config(path: Path | None):
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.ident.vertex import IdentificationConfig
    from lpv_sysid.io.files import read_yaml_mapping

    if path is None:
        return IdentificationConfig()
    d = read_yaml_mapping(path)  # an explicitly given empty or non-mapping file is an error
    try:
        return IdentificationConfig.from_dict(d)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def quadrotor_section(path: Path | None) -> dict:
    """The ``quadrotor`` section of config/quadrotor.yaml (``{}`` without a file)."""
    if path is None:
        return {}
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.io.files import read_yaml_mapping

    d = read_yaml_mapping(path)
    q = d.get("quadrotor", {})
    if not isinstance(q, dict):
        raise ConfigError(f"{path}: section 'quadrotor' must be a mapping")
    return q


def format_r2_table(results) -> str:
    from lpv_sysid.ident.metrics import AXES

    lines = [
        "LTI equation-error coefficient of determination R^2 [%] (seed 0 Table 2)",
        f"{'Nominal vertex':>18} " + " ".join(f"{a:>7}" for a in AXES),
    ]
    for r in results:
        vtx = "[" + " ".join(f"{c:+g}" for c in r.scheduling) + "]"
        lines.append(f"{vtx:>18} " + " ".join(f"{100 * r.r2_axes[a]:7.1f}" for a in AXES))
    return "\n".join(lines)


def format_validation_table(val: dict) -> str:
    from lpv_sysid.ident.metrics import AXES

    return "\n".join(
        [
            "LPV model validation metrics (seed 0 Table 3)",
            f"{'Axis':>6} " + " ".join(f"{a:>7}" for a in AXES),
            f"{'TIC':>6} " + " ".join(f"{val['tic'][a]:7.3f}" for a in AXES),
            f"{'NRMSE':>6} " + " ".join(f"{val['nrmse'][a]:7.3f}" for a in AXES),
        ]
    )


def data_label(bags: str | Path) -> str:
    """SIMULATED / SITL / HITL / SIH / FLOWN of the bags: the vehicle kind their
    ``experiment.yaml`` records (report.gonogo.vehicle_label); none: ``simulate phase1``."""
    from lpv_sysid.errors import LpvSysidError
    from lpv_sysid.io.files import read_yaml
    from lpv_sysid.report import SIMULATED, vehicle_label

    meta = Path(bags) / "experiment.yaml"
    if not meta.is_file():
        return SIMULATED
    try:
        return vehicle_label(read_yaml(meta))[0]
    except LpvSysidError:
        return "source unknown"


def format_output_error_table(oe: dict) -> str:
    axes = list(oe["nrmse"])
    return "\n".join(
        [
            f"Output-error (free-run) validation, restarted every {oe['horizon_s']:.2f} s",
            f"{'State':>6} " + " ".join(f"{a:>7}" for a in axes),
            f"{'TIC':>6} " + " ".join(f"{oe['tic'][a]:7.3f}" for a in axes),
            f"{'NRMSE':>6} " + " ".join(f"{oe['nrmse'][a]:7.3f}" for a in axes),
        ]
    )


def format_offset_table(results) -> str:
    """The identified model's derivative at the flown trim mean (it is not an equilibrium;
    the vertex models are re-expanded about the equilibrium instead)."""
    from lpv_sysid.ident.metrics import AXES

    lines = [
        "Identified state derivative at the flown trim mean (not an equilibrium)",
        f"{'Vertex':>18} " + " ".join(f"{a:>8}" for a in AXES),
    ]
    for r in results:
        if r.xdot_flown is not None:
            vtx = "[" + " ".join(f"{c:+g}" for c in r.scheduling) + "]"
            lines.append(f"{vtx:>18} " + " ".join(f"{v:8.4f}" for v in r.xdot_flown[2:8]))
    return "\n".join(lines)


def format_uncertainty_summary(results, cfg) -> str:
    """One line per vertex: identified elements, motor constants, dof and widening of the std."""
    from lpv_sysid.ident.equation_error import t_factor
    from lpv_sysid.ident.vertex import applied_k

    lines = [
        f"uncertainty box of Eq. (22): every identified element, nominal +/- k std (k = "
        f"{cfg.uncertainty.k_sigma:g}); std {cfg.covariance.method}"
    ]
    for r in results:
        vtx = "[" + " ".join(f"{c:+g}" for c in r.scheduling) + "]"
        k = applied_k(cfg.uncertainty, len(r.uncertain.intervals))
        m = r.motor.get("mode", "known")
        if m == "identified":
            mot = (
                f"a_Omega {-r.fit.A[8, 8]:.4g} +/- {r.fit.std_A[8, 8]:.2g}, b_Omega "
                f"{r.fit.B[8, 0]:.5g} +/- "
                f"{r.fit.std_B[8, 0]:.3g}, latency {1e3 * r.motor.get('delay', 0.0):.3f} ms"
            )
        elif m == "prior":
            mot = f"a_Omega, b_Omega from the other maneuvers ({r.motor.get('reason', '')})"
        else:
            mot = f"a_Omega, b_Omega known ({r.motor.get('reason', '')})"
        dof = (
            ""
            if r.fit.dof is None
            else f", dof {r.fit.dof:.0f} (std x {t_factor(k, r.fit.dof):.3f})"
        )
        lines.append(
            f"{vtx:>18}: {len(r.uncertain.intervals)} elements{dof}; {mot}; reduced polytope "
            f"M_i = {r.uncertain.M} ({cfg.uncertainty.method}, p_max={cfg.uncertainty.p_max})"
        )
    return "\n".join(lines)


def run_rate_plant(args: argparse.Namespace) -> int:
    """``--plant px4-rate`` (module docstring)."""
    import math

    from lpv_sysid.configuration.defaults import config_file
    from lpv_sysid.errors import ConfigError, LpvSysidError
    from lpv_sysid.flight.campaign import FlyConfig
    from lpv_sysid.flight.chain import campaign_bags, identify_rate_runs
    from lpv_sysid.ident import rate_plant as rid

    if not (math.isfinite(args.k_sigma) and 0.0 <= args.k_sigma <= 10.0):
        raise ConfigError(f"--k-sigma must be in [0, 10], got {args.k_sigma!r}")
    cfg = FlyConfig.load(args.campaign or config_file("campaign_chain.yaml"))
    runs = []
    for d in args.bags:
        for b in campaign_bags(d):
            try:
                runs.append(rid.read_run(b))
            except LpvSysidError as exc:
                print(f"skipped {b}: {exc}")
    if not runs:
        raise ConfigError(
            f"{' '.join(map(str, args.bags))}: no bag with state and rate_setpoint (PX4's "
            "ATTITUDE_TARGET): fly phase 1 with --record-rate-setpoints (the chain does)"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    c = cfg.campaign
    identify_rate_runs(runs, c.box_min, c.box_max, args.k_sigma, args.out, print)
    return 0


def run(args: argparse.Namespace) -> int:
    import dataclasses

    if args.plant == "px4-rate":
        return run_rate_plant(args)

    from lpv_sysid.ident import dataprep as dp
    from lpv_sysid.ident import metrics
    from lpv_sysid.ident import vertex as vx
    from lpv_sysid.ident.phase1 import identify_campaign
    from lpv_sysid.io.formats import VertexModels, save_models_mat

    cfg = load_config(args.config)
    if args.quadrotor is not None:
        cfg = dataclasses.replace(cfg, quadrotor=quadrotor_section(args.quadrotor))
    if len(args.bags) != 1:
        from lpv_sysid.errors import ConfigError

        raise ConfigError(
            f"--bags: the quadrotor plant takes one campaign directory, got {len(args.bags)} "
            "(several flights: --plant px4-rate)"
        )
    ident = identify_campaign(args.bags[0], cfg)
    for note in ident.notes:
        print(note)
    results, val = ident.results, ident.validation
    print("Flight data vertex equilibria (seed 0 Table 1: the flown trim means)")
    print(
        dp.format_table1(
            [
                (
                    [float(c) for c in r.scheduling],
                    dp.trim_row(r.x_flown if r.x_flown is not None else r.x0),
                )
                for r in results
            ]
        )
    )
    if cfg.model == "taylor2" and cfg.equilibrium:
        print()
        print(
            "Equilibria of the identified models at the flown velocities (the models' x0, Eq. 13)"
        )
        print(
            dp.format_table1(
                [([float(c) for c in r.scheduling], dp.trim_row(r.x0)) for r in results]
            )
        )
        print()
        print(format_offset_table(results))
    print()
    print(format_r2_table(results))
    if val is not None:
        print()
        print(format_validation_table(val))
        if val.get("output_error"):
            print()
            print(format_output_error_table(val["output_error"]))
    doc = vx.vertex_models_dict(results, cfg, val)
    models = VertexModels.from_dict(doc)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    sha = models.save(args.out)
    print()
    print(format_uncertainty_summary(results, cfg))
    print(f"wrote {args.out} (sha256 {sha[:12]})")
    mat = save_models_mat(models, args.out.with_suffix(".mat"))
    print(f"wrote {mat} (MATLAB: A, B, x0, u0 per vertex, uncertain intervals)")
    if val is not None:
        plot = args.plot or args.out.with_name(args.out.stem + "_validation.png")
        metrics.plot_validation(
            val["t"],
            val["xdot_m"],
            val["xdot_f"],
            str(plot),
            title=f"[{data_label(args.bags[0])}] LPV model independent validation (seed 0 Fig. 4)",
        )
        print(f"wrote {plot}")
    return 0
