"""`lpv-sysid demo`: the whole two-phase job on the simulated quadrotor, end to end.

Runs the same subcommands a flight-test engineer runs, in order (seed 0 Secs. IV-VII):
phase-1 flights -> signal design -> vertex identification -> robust LPV synthesis ->
independent verification -> phase-2 flight -> report. Each step's artefacts land in
``--out``; the run stops at the first failing step and says which.

``--connect URL`` runs the same chain on a connected PX4 instead (:mod:`lpv_sysid.flight.chain`,
``lpv-sysid chain``): rate plant, real flights, docs/px4_chain.md.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

from lpv_sysid.configuration.defaults import config_file
from lpv_sysid.errors import LpvSysidError

COMMAND = "demo"
HELP = (
    "run phase 1 -> identify -> synthesize -> verify -> phase 2 -> report on the simulated vehicle"
)

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="demo_out", help="output directory (default demo_out)")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="short flights (phase-1 durations x0.5, 2 phase-2 periods less) for a fast look",
    )
    parser.add_argument(
        "--kappa", type=float, default=1.0, help="phase-2 excitation multiplier (seed 0 Eq. 33)"
    )
    parser.add_argument(
        "--connect",
        default=None,
        metavar="URL",
        help="fly the chain on a connected PX4 instead (same as `lpv-sysid chain --connect URL "
        "--out DIR`: rate plant, docs/px4_chain.md); without it: the simulated vehicle",
    )
    parser.add_argument(
        "--set-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="with --connect: PARAM_SET before phase 1 (e.g. COM_OBL_RC_ACT=5 COM_OF_LOSS_T=2)",
    )


def plan(out: Path, quick: bool, kappa: float) -> list[tuple[str, list[str]]]:
    """The demo's steps as (title, lpv-sysid argv) pairs."""
    quad = str(config_file("quadrotor.yaml"))
    phase1 = ["simulate", "phase1", "--config", quad, "--out", str(out / "phase1")]
    if quick:
        phase1 += ["--duration-scale", "0.5"]
    return [
        ("phase-1 flights at the 8 box vertices + hover validation", phase1),
        (
            "phase-2 reference and excitation multisines",
            [
                "signals",
                "--config",
                str(config_file("signals_phase2.yaml")),
                "--out",
                str(out / "signals"),
                "--force",  # a re-run rewrites the gains that refer to it, in this same run
            ],
        ),
        (
            "vertex identification (equation error, seed 0 App. B)",
            [
                "identify",
                "--bags",
                str(out / "phase1"),
                "--config",
                str(config_file("identification.yaml")),
                "--quadrotor",
                quad,
                "--out",
                str(out / "vertex_models.yaml"),
                "--plot",
                str(out / "identification.png"),
            ],
        ),
        (
            "robust LPV H-infinity synthesis (seed 0 Lemma 1)",
            [
                "synthesize",
                "--models",
                str(out / "vertex_models.yaml"),
                "--config",
                str(config_file("synthesis.yaml")),
                "--summary",
                str(out / "signals" / "summary.yaml"),
                "--out",
                str(out / "gains.yaml"),
            ],
        ),
        (
            "independent verification of the certificate",
            [
                "verify",
                "--gains",
                str(out / "gains.yaml"),
                "--models",
                str(out / "vertex_models.yaml"),
            ],
        ),
        (
            "phase-2 flight under the LPV law",
            [
                "simulate",
                "phase2",
                "--gains",
                str(out / "gains.yaml"),
                "--models",
                str(out / "vertex_models.yaml"),
                "--signals",
                str(out / "signals"),
                "--config",
                quad,
                "--kappa",
                str(kappa),
                "--feedforward",
                "filtered",  # the onboard path: derivatives of the v_d stream
                "--out",
                str(out / "phase2"),
            ],
        ),
        ("report", ["report", "--run", str(out), "--out", str(out / "report" / "report.md")]),
    ]


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.cli.main import main as cli_main

    from lpv_sysid.control.law import check_kappa

    check_kappa(args.kappa, positive=True)  # before step 1, not at step 6 after 20-37 s
    out = Path(args.out)
    if getattr(args, "connect", None):
        from lpv_sysid.cli.vehicle import parse_params
        from lpv_sysid.flight.chain import chain

        return chain(args.connect, out, params=parse_params(args.set_param), kappa=args.kappa)
    out.mkdir(parents=True, exist_ok=True)
    steps = plan(out, args.quick, args.kappa)
    t_start = time.monotonic()
    verbosity = ["-v"] * getattr(args, "verbose", 0)  # a step's traceback with the demo's -v
    for k, (title, argv) in enumerate(steps, 1):
        sys.stdout.flush()  # progress (stderr) after the previous step's results (stdout)
        log.info("[%d/%d] %s: lpv-sysid %s", k, len(steps), title, " ".join(argv))
        t0 = time.monotonic()
        rc = cli_main(verbosity + argv)
        if rc != 0:
            raise LpvSysidError(
                f"step {k} ({title}) failed with exit status {rc}; artefacts so far are in {out}"
            )
        sys.stdout.flush()
        log.info("[%d/%d] done in %.1f s", k, len(steps), time.monotonic() - t0)
    print(f"\ndemo finished in {time.monotonic() - t_start:.0f} s")
    print(f"gains file: {out / 'gains.yaml'}")
    print(f"report:     {out / 'report' / 'report.md'}")
    return 0
