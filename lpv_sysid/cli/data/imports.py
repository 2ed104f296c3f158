"""`lpv-sysid import ulog LOG.ulg --out DIR` / `lpv-sysid import bag BAG --out DIR`: flight
data recorded with other tools -> the package's bags (one rosbag2 per run) and
``experiment.yaml`` with the provenance, so ``identify --bags DIR`` and ``report`` read it.

    lpv-sysid import ulog log/2026-12-02/10_31_07.ulg --out flight_07
    lpv-sysid import ulog LOG.ulg --out runs --window 31.5:52:vertex_0 --window 60:81
    lpv-sysid import bag rosbag2_2026_12_02 --out flight_08      # MAVROS or /fmu/out bag

Runs are the offboard segments of the log unless ``--window START:END[:NAME]`` (seconds on
the log's clock: since PX4 boot for a ULog / px4_msgs bag, since the first odometry message
for a MAVROS bag) gives them. Prints one line per run written.
"""

from __future__ import annotations

import argparse
from datetime import datetime, timezone

COMMAND = "import"
HELP = "import a PX4 ULog or a MAVROS / px4_msgs rosbag2 as the package's bags"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from lpv_sysid.io.imports import VEHICLE_KINDS

    actions = parser.add_subparsers(dest="action", metavar="KIND")
    actions.required = True
    for kind, what in (
        ("ulog", "a PX4 ULog file (.ulg)"),
        ("bag", "a rosbag2 directory recorded from MAVROS or PX4's uXRCE-DDS (/fmu/out)"),
    ):
        p = actions.add_parser(kind, help=f"import {what}", description=__doc__.split("\n\n")[0])
        p.add_argument("source", metavar="LOG" if kind == "ulog" else "BAG", help=what)
        p.add_argument("--out", required=True, metavar="DIR", help="output directory (new)")
        p.add_argument(
            "--window",
            action="append",
            default=[],
            metavar="START:END[:NAME]",
            help="a run's interval in seconds on the log's clock (repeatable; default: the "
            "offboard segments)",
        )
        p.add_argument(
            "--min-duration",
            type=float,
            default=1.0,
            metavar="S",
            help="shortest offboard segment taken as a run (s, default 1)",
        )
        p.add_argument(
            "--epoch",
            default=None,
            metavar="ISO|SECONDS",
            help="wall-clock time of the PX4 boot when the log has no GPS time "
            "(ISO 8601 UTC or Unix seconds); default: stamps stay time since boot",
        )
        p.add_argument(
            "--clock-from",
            default=None,
            metavar="DIR",
            help="a `fly` recording of the same flight (its experiment.yaml): stamp the "
            "imported bags on its clock (PX4 boot offset and rate fitted from MAVLink), so "
            "both line up; --window is then still in seconds since PX4 boot",
        )
        p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
        p.add_argument(
            "--vehicle-kind",
            choices=VEHICLE_KINDS,
            default=None,
            help="what the data come from, when the source does not say (report label)",
        )
        p.set_defaults(_kind=kind)


def parse_epoch(text: str | None) -> int | None:
    """``--epoch`` -> ns since the Unix epoch (ValueError with the reason)."""
    if text is None:
        return None
    try:
        return int(round(float(text) * 1e9))
    except ValueError:
        pass
    dt = datetime.fromisoformat(text.replace("Z", "+00:00"))
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=timezone.utc)
    return int(round(dt.timestamp() * 1e9))


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.io import imports

    try:
        epoch = parse_epoch(args.epoch)
    except ValueError as exc:
        raise ConfigError(f"--epoch {args.epoch!r}: {exc}") from None
    if args._kind == "ulog":
        rec = imports.read_ulog(args.source, epoch_ns=epoch)
    else:
        rec = imports.read_foreign_bag(args.source, epoch_ns=epoch)
    if args.clock_from is not None:
        rec.clock_offset_ns, rec.clock_rate, rec.clock_knots = imports.px4_clock_of(
            args.clock_from
        )
        rec.clock = "recording"
    runs = imports.import_flight(
        rec, args.out, args.window, args.storage, args.min_duration, args.vehicle_kind
    )
    for r in runs:
        print(
            f"{args.out}/{r.bag}: {r.name} [{r.start:.3f}, {r.end:.3f}] s, {r.messages} messages"
        )
    kind = rec.provenance.get("vehicle_kind", "UNKNOWN")
    print(f"{args.out}/experiment.yaml: {len(runs)} run(s), vehicle {kind}, clock {rec.clock}")
    for note in rec.notes:
        print(f"note: {note}")
    return 0
