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
HELP = "simulate the phase-1 (baseline control) or phase-2 (LPV control) experiment and write rosbag2 logs"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    modes = parser.add_subparsers(dest="mode", metavar="MODE")
    modes.required = True
    p1 = modes.add_parser("phase1", help="vertex runs under the baseline controller (seed 0 Sec. IV)",
                          description="Phase 1: 10 s trim + 30 s 4-axis multisine at each vertex "
                                      "of the velocity box, plus a hover validation run.")
    _add_phase1_arguments(p1)
    p1.set_defaults(_mode_run=run_phase1)
    from lpv_sysid.sim.phase2 import add_phase2_arguments, run_phase2

    p2 = modes.add_parser("phase2", help="LPV-controlled large-amplitude excitation (seed 0 Secs. V-VII)",
                          description="Phase 2: the Eq. (33) LPV closed loop at nominal parameters and "
                                      "the nonlinear quadrotor under the runtime LPV law, with the "
                                      "7-channel reference/excitation signals; writes a rosbag2.")
    add_phase2_arguments(p2)
    p2.set_defaults(_mode_run=run_phase2)


def _add_phase1_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", required=True, help="YAML with sections quadrotor, controller, sim, phase1")
    p.add_argument("--out", required=True, help="output directory (created)")
    p.add_argument("--duration-scale", type=float, default=1.0,
                   help="multiply trim/excitation durations (quick runs), default 1")
    p.add_argument("--vertices", type=int, nargs="+", default=None, metavar="I",
                   help="1-based vertex indices in seed 0 Table 1 order (default: all 8)")
    p.add_argument("--no-hover", action="store_true", help="skip the hover validation run")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="rosbag2 storage")
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
    model = Quadrotor(qp)
    t0 = time.perf_counter()
    runs = phase1.run_phase1(model, gains, sensors, cfg, args.vertices)
    print(f"simulated {len(runs)} run(s) in {time.perf_counter() - t0:.1f} s")
    if not args.no_bags:
        for rec in runs:
            path = out / rec.name
            phase1.write_run_bag(rec, path, storage=args.storage)
            print(f"wrote {path}")
    rows = phase1.trim_table(runs, cfg, qp.arm_length)
    y, m = phase1.write_trim_table(rows, out)
    print(f"wrote {y}")
    print(f"wrote {m}")
    print(phase1.format_trim_table(rows))
    return 0
