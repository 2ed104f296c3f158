"""`lpv-sysid simulate`: experiment simulation, phase 1 and phase 2.

``lpv-sysid simulate phase1 --config config/quadrotor.yaml --out DIR`` flies the seed 0
Sec. IV vertex runs plus the hover validation run under the PX4-like baseline controller,
writes one rosbag2 directory per run and trims.yaml / trims.md, and prints them.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from lpv_sysid.errors import ConfigError

COMMAND = "simulate"
HELP = (
    "simulate the phase-1 (baseline control) or phase-2 (LPV control) experiment and write "
    "rosbag2 logs"
)

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    modes = parser.add_subparsers(dest="mode", metavar="MODE")
    modes.required = True
    p1 = modes.add_parser(
        "phase1",
        help="vertex runs under the baseline controller (seed 0 Sec. IV)",
        description="Phase 1: 10 s trim + 30 s 4-axis multisine at each vertex "
        "of the velocity box, plus a hover validation run.",
    )
    _add_phase1_arguments(p1)
    p1.set_defaults(_mode_run=run_phase1)
    p2 = modes.add_parser(
        "phase2",
        help="LPV-controlled large-amplitude excitation (seed 0 Secs. V-VII)",
        description="Phase 2: the Eq. (33) LPV closed loop at nominal parameters and "
        "the nonlinear quadrotor under the runtime LPV law, with the "
        "7-channel reference/excitation signals; writes a rosbag2.",
    )
    _add_phase2_arguments(p2)
    p2.set_defaults(_mode_run=run_phase2)


def _add_phase1_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--config", required=True, help="YAML with sections quadrotor, controller, sim, phase1"
    )
    p.add_argument("--out", required=True, help="output directory (created)")
    p.add_argument(
        "--duration-scale",
        type=float,
        default=1.0,
        help="multiply trim/excitation durations (quick runs), default 1",
    )
    p.add_argument(
        "--vertices",
        type=int,
        nargs="+",
        default=None,
        metavar="I",
        help="1-based vertex indices in seed 0 Table 1 order (default: all 8)",
    )
    p.add_argument("--no-hover", action="store_true", help="skip the hover validation run")
    p.add_argument(
        "--storage", choices=("mcap", "sqlite3"), default="mcap", help="rosbag2 storage"
    )
    p.add_argument(
        "--epoch",
        default="2026-01-01T00:00:00Z",
        metavar="ISO|SECONDS",
        help="wall-clock time the simulated runs are stamped from (each run starts there; "
        "default 2026-01-01T00:00:00Z, a declared date, not the time of the simulation)",
    )
    p.add_argument("--no-bags", action="store_true", help="only write the trim table")


def run(args: argparse.Namespace) -> int:
    return int(args._mode_run(args) or 0)


def run_phase1(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from lpv_sysid.models.quadrotor import Quadrotor
    from lpv_sysid.sim import phase1

    qp, gains, sensors, cfg = phase1.load_config(args.config)
    cfg = cfg.scaled(args.duration_scale)
    if args.no_hover:
        cfg = replace(cfg, hover_validation=False)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--out {out}: cannot create ({exc.strerror})") from None
    from lpv_sysid.cli.data.imports import parse_epoch

    try:
        epoch_ns = parse_epoch(args.epoch) or 0
    except ValueError as exc:
        raise ConfigError(f"--epoch {args.epoch!r}: {exc}") from None
    model = Quadrotor(qp)
    t0 = time.perf_counter()
    runs = phase1.run_phase1(model, gains, sensors, cfg, args.vertices)
    print(f"simulated {len(runs)} run(s) in {time.perf_counter() - t0:.1f} s")
    if not args.no_bags:
        for rec in runs:
            path = out / rec.name
            phase1.write_run_bag(rec, path, storage=args.storage, epoch_ns=epoch_ns)
            print(f"wrote {path}")
    rows = phase1.trim_table(runs, cfg, qp.arm_length)
    y, m = phase1.write_trim_table(rows, out)
    print(f"wrote {y}")
    print(f"wrote {m}")
    print(phase1.format_trim_table(rows))
    return 0


def _add_phase2_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``lpv-sysid simulate phase2``."""
    parser.add_argument("--gains", required=True, type=Path, help="gains.yaml (lpv_sysid/gains@1)")
    parser.add_argument(
        "--signals",
        required=True,
        type=Path,
        help="directory with signals.npz (7 channels u_d, v_d, w_d, ue_t, ue_a, ue_e, ue_r)",
    )
    parser.add_argument("--out", required=True, type=Path, help="output directory (created)")
    parser.add_argument(
        "--models",
        type=Path,
        default=None,
        help="vertex_models.yaml for the Eq. (33) simulation (default: next to --gains)",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="YAML with sections quadrotor and sim (default: built-in FlameWheel-450 "
        "parameters, default sensors)",
    )
    parser.add_argument(
        "--kappa", type=float, default=1.0, help="excitation multiplier of Eq. (33), default 1"
    )
    parser.add_argument(
        "--duration", type=float, default=None, help="simulate only the first SECONDS"
    )
    parser.add_argument(
        "--ramp",
        type=float,
        default=2.0,
        help="fade in/out of the excitation player in s (0: play the raw table), default 2",
    )
    parser.add_argument(
        "--eq33-method",
        choices=("rk4", "RK45"),
        default="rk4",
        help="integrator of Eq. (33): fixed-step RK4 on the signal grid (default) or "
        "scipy RK45 (ode45's method)",
    )
    parser.add_argument(
        "--box-margin",
        type=float,
        default=1.0,
        help="m/s beyond the scheduling box before the safety supervisor stops the run",
    )
    parser.add_argument(
        "--max-tilt", type=float, default=60.0, help="roll/pitch limit of the supervisor, deg"
    )
    parser.add_argument(
        "--monitor-margin",
        type=float,
        default=1.2,
        help="bound monitor of the runtime law flags when the running ||z||/||kappa u_e|| "
        "exceeds gamma x MARGIN (the flag stops the run), default 1.2",
    )
    parser.add_argument(
        "--feedforward",
        choices=("exact", "filtered", "off"),
        default="exact",
        help="reference feedforward of the nonlinear run when gains.yaml has F_ff: exact "
        "(derivative of the signal table), filtered (the onboard derivative filter) or off",
    )
    parser.add_argument(
        "--ff-filter-tau",
        type=float,
        default=0.05,
        help="time constant (s) of the onboard derivative filter (--feedforward filtered)",
    )
    parser.add_argument(
        "--ff-jerk-tau",
        type=float,
        default=0.2,
        help="time constant (s) of its jerk stage (--feedforward filtered)",
    )
    parser.add_argument(
        "--monitor-window",
        type=float,
        default=None,
        help="bound monitor over an exponentially forgetting window of SECONDS "
        "(default: running from the start)",
    )
    parser.add_argument(
        "--storage", choices=("mcap", "sqlite3"), default="mcap", help="rosbag2 storage"
    )
    parser.add_argument("--no-bag", action="store_true", help="do not record the rosbag2")
    parser.add_argument("--skip-eq33", action="store_true", help="only the nonlinear simulation")
    parser.add_argument(
        "--skip-nonlinear", action="store_true", help="only the Eq. (33) simulation"
    )
    parser.add_argument(
        "--seed", type=int, default=None, help="sensor-noise seed (default: from --config)"
    )
    parser.add_argument(
        "--superposition",
        action="store_true",
        help="two more nonlinear flights (with / without u_e, same noise) to estimate the "
        "excitation-only gain ||z_e||/||kappa u_e||, comparable with gamma",
    )


def format_gain_line(rec, gamma) -> str:
    """One run's ratios, the u_e -> z gain (what gamma bounds) first, the rest named apart
    (sim.phase2 module docstring)."""
    state = "completed" if rec.completed else f"STOPPED: {rec.safety_event}"
    d = rec.decomposition or {}
    g = rec.excitation_gain
    if g is None:
        head = "u_e -> z gain not separated"
    else:
        head = f"u_e -> z gain {g:.3g}" + (
            f" ({'<=' if g <= gamma else '>'} gamma {gamma:g})" if gamma else ""
        )
    parts = [f"total ||z||/||kappa u_e|| {rec.gain:.3g}"]
    for key, label in (
        ("offset", "equilibrium offset"),
        ("tracking", "tracking"),
        ("tracking_and_excitation", "tracking + excitation"),
    ):
        r = (d.get(key) or {}).get("ratio")
        if r is not None:
            parts.append(f"{label} {r:.3g}")
    how = f" [{d['method']}]" if d.get("method") else ""
    return f"{head}{how}; {', '.join(parts)} (norm ratios, not additive); {state}"


def run_phase2(args: argparse.Namespace) -> int:
    """``lpv-sysid simulate phase2``: prints what it wrote; LpvSysidError on bad input."""
    from lpv_sysid.report import write_phase2_figures
    from lpv_sysid.sim.phase2 import (
        Phase2Config,
        load_problem,
        load_signals,
        load_vehicle_config,
        run,
    )

    cfg = Phase2Config(
        kappa=args.kappa,
        eq33_method=args.eq33_method,
        box_margin=args.box_margin,
        max_tilt_deg=args.max_tilt,
        duration=args.duration,
        ramp=None if not args.ramp else float(args.ramp),
        record_bag=not args.no_bag,
        storage=args.storage,
        run_eq33=not args.skip_eq33,
        run_nonlinear=not args.skip_nonlinear,
        monitor_margin=args.monitor_margin,
        superposition=args.superposition,
        feedforward=args.feedforward,
        ff_filter_tau=args.ff_filter_tau,
        ff_jerk_tau=args.ff_jerk_tau,
        monitor_window=args.monitor_window,
    )
    models_path = (
        args.models if args.models is not None else Path(args.gains).parent / "vertex_models.yaml"
    )
    problem = load_problem(
        args.gains, models_path if (args.models is not None or models_path.is_file()) else None
    )
    signals = load_signals(args.signals, cfg.duration, cfg.ramp, design=problem.design)
    quad_params, sensors = load_vehicle_config(args.config, args.seed)
    out = Path(args.out)
    t0 = time.perf_counter()
    result = run(problem, signals, cfg, quad_params, sensors, out)
    figures = write_phase2_figures(
        out,
        list(result.records.values()),
        result.regressor_block,
        box=(problem.vmin.tolist(), problem.vmax.tolist()),
    )
    print(
        f"simulated phase 2 in {time.perf_counter() - t0:.1f} s (kappa = {cfg.kappa:g}, gamma = "
        f"{problem.gamma if problem.gamma is not None else 'n/a'})"
    )
    for name in ("eq33", "linear_ff", "nonlinear"):
        rec = result.records.get(name)
        if rec is not None:
            print(f"  {name:9s}: {format_gain_line(rec, problem.gamma)}")
        elif name in result.skipped:
            print(f"  {name:9s}: skipped ({result.skipped[name]})")
    written = dict(result.written)
    bag = written.pop("bag", None)
    for path in [*written.values(), *figures.values(), *([bag] if bag else [])]:
        print(f"wrote {path}")
    return 0
