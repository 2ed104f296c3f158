"""`lpv-sysid fly`: fly on a PX4 vehicle over MAVLink (no ROS).

    lpv-sysid fly phase1 --connect udpin:127.0.0.1:14540 --config config/campaign.yaml \\
        --out flight_01 [--signals signals_phase1/signals.npz] [--set-param COM_OBL_RC_ACT=5]
    lpv-sysid fly phase2 --connect URL --gains G --models M --signals S --out DIR

``phase1``: the campaign of :mod:`lpv_sysid.flight.campaign` (take-off in OFFBOARD, every
vertex and the hover run, HOLD or LAND; one rosbag2 per run for `lpv-sysid identify`).
Before anything arms (phase 1) or takes control (phase 2) the operator confirms on the
terminal; ``--yes`` confirms in advance, and without a terminal (stdin not a TTY) the
command refuses unless ``--yes`` is given. ``--set-param`` changes are set back when the
flight ends. ``--dry-run`` prints the plan, total time, battery estimate and airspace.
``phase2``: the phase-2 signal under the LPV law on a vehicle already armed and in the air
(:mod:`lpv_sysid.flight.phase2`). Ctrl-C (or SIGTERM) or any fault: excitation off,
hand-back confirmed by the HEARTBEAT (or FAILED loudly), bags closed and readable, exit
status 1 (130 after an interrupt) with the reason. A second Ctrl-C stops waiting for the
confirmation.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from lpv_sysid.control.campaign import DEFAULT_ENDURANCE_S, PLAN_COLUMNS
from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.campaign import EXIT_FAILED, FlyConfig, fly, plan_flight, resume_config

COMMAND = "fly"
HELP = (
    "fly on a PX4 vehicle over MAVLink: phase1 = campaign (take-off, vertices, hover, land, "
    "rosbag2); "
    "phase2 = LPV law on the rate plant (lpv_sysid/flight/phase2)"
)


# ================================================================================== CLI
def add_arguments(parser: argparse.ArgumentParser) -> None:
    modes = parser.add_subparsers(dest="mode", metavar="MODE")
    modes.required = True
    p = modes.add_parser(
        "phase1",
        help="phase-1 campaign: take-off, every vertex + hover validation, land",
        description="Arm and take off in OFFBOARD, fly every vertex of the body-velocity "
        "box (settle, trim, phase-1 multisine) and the hover validation run, "
        "then HOLD or LAND; one rosbag2 per run for `lpv-sysid identify`. "
        "Preflight NO-GO refuses to fly; Ctrl-C hands control back.",
    )
    p.add_argument(
        "--connect",
        required=True,
        metavar="URL",
        help="MAVLink URL, e.g. udpin:127.0.0.1:14540 (PX4 SITL) or /dev/ttyAMA0:921600",
    )
    p.add_argument("--config", required=True, type=Path, help="config/campaign.yaml")
    p.add_argument("--out", required=True, type=Path, help="output directory (new or empty)")
    p.add_argument(
        "--signals",
        default=None,
        help="phase-1 signals.npz (`lpv-sysid signals`); "
        "default: designed from the config's signals_config",
    )
    p.add_argument(
        "--set-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="PARAM_SET before preflight, confirmed by the vehicle (repeatable), "
        "e.g. COM_OBL_RC_ACT=5 on a SITL without RC",
    )
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="load and plan only; print the plan, total time, battery use and airspace, exit",
    )
    p.add_argument(
        "--endurance-min",
        type=float,
        default=DEFAULT_ENDURANCE_S / 60.0,
        metavar="MIN",
        help="hover endurance of one battery [min] for the battery estimate and preflight's "
        "battery check (default %(default)g)",
    )
    p.add_argument(
        "--yes",
        action="store_true",
        help="do not ask before arming (needed when stdin is not a terminal)",
    )
    p.add_argument(
        "--resume",
        type=Path,
        default=None,
        metavar="DIR",
        help="continue the campaign a stopped flight (its output DIR) did not complete: fly "
        "only the runs not complete there (identify then takes --bags DIR OUT)",
    )
    p2 = modes.add_parser(
        "phase2",
        help="phase-2 flight under the LPV law (rate plant) on a vehicle in the air",
        description="Take the armed, airborne vehicle (e.g. in HOLD after `fly phase1` with "
        "finish: HOLD) into OFFBOARD with the LPV law's thrust + body-rate "
        "setpoints (rate plant, lpv_sysid/flight/phase2), fly the phase-2 signal, "
        "hand back (LAND); bag, phase2_summary.yaml with the measured u_e -> z gain.",
    )
    p2.add_argument("--connect", required=True, metavar="URL", help="MAVLink URL")
    p2.add_argument(
        "--gains", required=True, help="rate-plant gains.yaml (lpv-sysid chain / synthesize)"
    )
    p2.add_argument(
        "--models", default=None, help="vertex_models.yaml the gains were designed for (checked)"
    )
    p2.add_argument(
        "--signals", required=True, help="phase-2 signals directory (lpv-sysid signals)"
    )
    p2.add_argument(
        "--bridge-config",
        default=None,
        help="bridge config (default config/mavlink_bridge_chain.yaml)",
    )
    p2.add_argument("--out", required=True, type=Path, help="output directory (new or empty)")
    p2.add_argument(
        "--kappa", type=float, default=1.0, help="excitation multiplier (seed 0 Eq. 33)"
    )
    p2.add_argument(
        "--finish", default="LAND", choices=("LAND", "HOLD"), help="mode after the signal"
    )
    p2.add_argument(
        "--yes",
        action="store_true",
        help="do not ask before taking control (needed when stdin is not a terminal)",
    )
    p.add_argument(
        "--record-rate-setpoints",
        action="store_true",
        help="also record PX4's ATTITUDE_TARGET (thrust + body-rate setpoints) on rate_setpoint "
        "(rate-plant identification; request the stream, e.g. config/mavlink_bridge_chain.yaml)",
    )


def run(args: argparse.Namespace) -> int:
    if args.mode == "phase2":
        from lpv_sysid.control.law import check_kappa
        from lpv_sysid.flight.phase2 import Phase2Options, fly_phase2

        check_kappa(args.kappa)  # before connecting
        ask = confirmation(args.yes, when_asked=True)  # after every check of gains and signals
        s = fly_phase2(
            args.gains,
            args.signals,
            args.out,
            url=args.connect,
            models=args.models,
            bridge_config=args.bridge_config,
            opts=Phase2Options(kappa=args.kappa, finish=args.finish),
            echo=print,
            confirm=ask,
        )
        if s.get("confirmed") is False:
            print("lpv-sysid fly: not confirmed: nothing sent", file=sys.stderr)
            return EXIT_FAILED
        lat = s.get("latency_state_to_setpoint_ms") or {}
        if lat.get("commands"):
            print(
                f"loop latency (state stamp -> setpoint sent, {lat['commands']} commands): p50 "
                f"{lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms, max {lat['max']:.2f} ms"
            )
        print(
            f"phase 2 {'complete' if s.get('ok') else 'FAILED'}: {s.get('reason')}; "
            f"{args.out / 'phase2_summary.yaml'}"
        )
        return 0 if s.get("ok") else EXIT_FAILED
    cfg = FlyConfig.load(args.config)
    if not math.isfinite(args.endurance_min) or args.endurance_min <= 0:
        raise ConfigError(f"--endurance-min {args.endurance_min:g}: must be > 0 minutes")
    params = parse_params(args.set_param)  # a dry run checks them too
    resumed = None
    if args.resume is not None:
        cfg, done = resume_config(cfg, args.resume)
        resumed = {"dir": str(args.resume), "completed": done}
        print(f"resuming {args.resume}: {len(done)} run(s) complete there ({', '.join(done)})")
    if args.dry_run:
        plan = plan_flight(cfg, args.connect, args.signals)
        print(plan.describe())
        print(PLAN_COLUMNS)
        print(plan.budget(args.endurance_min * 60.0).describe())
        d = plan.demands()
        print(
            f"PX4 limits the box needs (checked by preflight): MPC_XY_VEL_MAX >= "
            f"{d.horizontal_speed:.2f} m/s, MPC_Z_VEL_MAX_UP >= {d.climb_speed:.2f} m/s, "
            f"MPC_Z_VEL_MAX_DN >= {d.descent_speed:.2f} m/s, MPC_TILTMAX_AIR >= "
            f"{d.tilt_deg:.2f} deg"
        )
        return 0
    ask = confirmation(args.yes)  # refuses before connecting when it cannot ask
    res = fly(
        cfg,
        args.connect,
        args.out,
        signals=args.signals,
        params=params,
        record_rate_setpoints=args.record_rate_setpoints,
        echo=print,
        confirm=ask,
        endurance_s=args.endurance_min * 60.0,
        resumed_from=resumed,
    )
    if res.status:
        print(f"lpv-sysid fly: {res.phase}: {res.reason}", file=sys.stderr)
    else:
        print(
            f"wrote {res.out_dir}: {len(res.summary.get('bags', {}))} bags, "
            "campaign_summary.yaml, "
            f"trims.yaml, identification.yaml"
        )
        print(
            f"next: lpv-sysid identify --bags {res.out_dir} --config "
            f"{Path(res.out_dir) / 'identification.yaml'} "
            f"--out vertex_models.yaml"
        )
    return res.status


def confirmation(yes: bool, when_asked: bool = False):
    """The operator's confirmation: None with ``--yes`` (not asked); a question on the
    terminal otherwise (only ``y`` / ``yes`` confirms); ConfigError when stdin is not a
    terminal (a script or a pipe cannot confirm: it must say ``--yes``) -- at once, or with
    ``when_asked`` when the question comes (after the checks of the files, which then refuse
    a bad file with their own words first)."""
    if yes:
        return None
    if not sys.stdin.isatty():
        why = (
            "refusing to fly without confirmation: stdin is not a terminal; "
            "pass --yes to confirm in advance"
        )
        if not when_asked:
            raise ConfigError(why)

        def refuse(question: str) -> bool:
            raise ConfigError(why)

        return refuse

    def ask(question: str) -> bool:
        print(question, flush=True)
        try:
            answer = input("type 'yes' to go, anything else aborts: ")
        except EOFError:
            return False
        return answer.strip().lower() in ("y", "yes")

    return ask


def parse_params(items) -> dict[str, float]:
    """``--set-param NAME=VALUE`` items -> {PX4 name: value}."""
    out: dict[str, float] = {}
    for it in items or ():
        name, sep, value = str(it).partition("=")
        name = name.strip().upper()
        if not sep or not name or len(name) > 16:
            raise ConfigError(
                f"--set-param {it!r}: expected NAME=VALUE (PX4 names have <= 16 characters)"
            )
        try:
            v = float(value)
        except ValueError:
            raise ConfigError(f"--set-param {it!r}: value is not a number") from None
        if not math.isfinite(v):
            raise ConfigError(f"--set-param {it!r}: value must be finite")
        out[name] = v
    return out
