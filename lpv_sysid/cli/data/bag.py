"""`lpv-sysid bag repair DIR...`: make a killed or starved recording readable again.

In the spirit of ``ros2 bag reindex``. ``DIR`` is an experiment directory of the data
logger (it has ``experiment.yaml``: every ``bag_NNNN`` in it is repaired, then
``experiment.yaml`` is made truthful -- ``status: incomplete``, counts = what the bags
hold; experiment directories nested one level down, like ``lpv-sysid fly``'s ``flight/``,
too) or a single rosbag2 directory. For mcap the unfinished tail a killed process left is
cut and the index (summary, footer) appended in place; for sqlite3 an uncommitted
transaction is rolled back; then ``metadata.yaml`` is written from what the storage holds,
so ``ros2 bag`` and rosbags' ``AnyReader`` open the bag. Nothing that was complete on disk
is rewritten or dropped. A directory a live recorder is writing is refused.

    lpv-sysid bag repair flight_07            # experiment directory
    lpv-sysid bag repair flight_07/bag_0002   # one bag
    lpv-sysid bag repair --dry-run flight_07  # report only

Prints one line per bag and per experiment; exit status 0 when every bag is readable,
1 when a bag could not be repaired (the line says why), 2 on bad input.

`lpv-sysid bag latency BAG...`: the loop's state-stamp -> setpoint latency p50/p99/max of a
phase-2 bag (``actuator_command``: log time minus header stamp, the stamp of the state sample
the command was computed on, controller ``tick_source: state``) -- the data logger's bag of
``phase2.launch.py`` or the bag of ``fly phase2`` (whose summary reports the same numbers,
:func:`lpv_sysid.flight.phase2.latency_from_bag`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

COMMAND = "bag"
HELP = (
    "rosbag2 maintenance: repair (reindex) a killed or starved recording so standard tools open it"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True
    p = actions.add_parser(
        "repair",
        help="cut an unfinished tail, rebuild the index and "
        "metadata.yaml, make experiment.yaml truthful",
        description=__doc__.split("\n\n")[1],
    )
    p.add_argument(
        "dirs",
        nargs="+",
        metavar="DIR",
        help="experiment directory (with experiment.yaml) or rosbag2 directory",
    )
    p.add_argument(
        "--dry-run", action="store_true", help="report what would be done, change nothing"
    )
    p.set_defaults(_action_run=run_repair)
    q = actions.add_parser(
        "latency",
        help="state-stamp -> setpoint latency p50/p99/max of a phase-2 bag (actuator_command)",
        description=__doc__.split("\n\n")[-1],
    )
    q.add_argument("bags", nargs="+", metavar="BAG", help="rosbag2 directory")
    q.set_defaults(_action_run=run_latency)


def run(args: argparse.Namespace) -> int:
    return int(args._action_run(args) or 0)


def run_repair(args: argparse.Namespace) -> int:
    from lpv_sysid.errors import BagError
    from lpv_sysid.io.bag import repair_bag
    from lpv_sysid.io.recorder import METADATA_FILE, repair_experiment

    status = 0
    for d in args.dirs:
        path = Path(d)
        if not path.is_dir():
            raise BagError(f"{path}: not a directory")
        if (path / METADATA_FILE).is_file():
            # the experiment and those nested in it (``lpv-sysid fly``: DIR/flight/)
            nested = [d for d in sorted(path.iterdir()) if (d / METADATA_FILE).is_file()]
            for exp in [path] + nested:
                rep = repair_experiment(exp, dry_run=args.dry_run)
                for r in rep.bags:
                    print(f"{exp}/{r.summary()}")
                print(f"{exp}/{rep.summary()}")
                status = max(status, 1 if rep.errors else 0)
        else:
            print(f"{path.parent}/{repair_bag(path, dry_run=args.dry_run).summary()}")
    return status


def run_latency(args: argparse.Namespace) -> int:
    from lpv_sysid.flight.phase2 import latency_from_bag

    for b in args.bags:
        lat = latency_from_bag(b)
        if not lat.get("commands"):
            print(f"{b}: no actuator_command")
            continue
        print(
            f"{b}: {lat['commands']} commands, state stamp -> setpoint latency p50 "
            f"{lat['p50']:.3f} ms, p99 {lat['p99']:.3f} ms, max {lat['max']:.3f} ms"
        )
    return 0
