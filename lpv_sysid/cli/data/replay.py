"""`lpv-sysid replay`: drive a node core with the recorded inputs of a bag, write its outputs.

    lpv-sysid replay --bag BAG --node lpv_controller --params config/lpv_controller.yaml \
        --out OUT_BAG [--gains gains.yaml]

The node's message-level runtime (the same code the node runs,
:mod:`lpv_sysid.flight.controller.replay`) receives the bag's input messages in
timestamp order (bag receive time) and its timer ticks at ``rate_hz`` on the bag's clock;
what it would have published (``actuator_command``, abort ``status``) is written to a new
bag. Ticks follow the node's ``tick_source``: ``timer`` steps the law at each timer tick
(one command per tick once every input has arrived: about one per state sample at 250 Hz
state and ``rate_hz`` 250), ``state`` steps it on each new state sample at its stamp (one
command per state sample) while the timer only judges staleness. The runtime is started
at the first input message, as with ``auto_start``. The
parameter file goes through the node's own declaration and validation
(:class:`~lpv_sysid.flight.controller.settings.ControllerSettings`: the same types, ranges and
cross-field rules, so a value the node would refuse is refused here too), and the gains
through the same start-up checks (certificate hash, closed-loop stability, design envelope).
Use it to check a gains file against a real flight log before flying: exit status 1 when
the replayed controller would have aborted (the reason is printed), 0 otherwise, 2 on bad
input.
"""

from __future__ import annotations

import logging
import os

from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.controller import replay_controller
from lpv_sysid.io.messages import TOPIC_NAMESPACE

COMMAND = "replay"
HELP = "replay a bag through a node core (lpv_controller) and write its outputs as a bag"
NODES = ("lpv_controller",)
LOG = logging.getLogger(__name__)


def add_arguments(parser) -> None:
    parser.add_argument(
        "--bag", required=True, help="rosbag2 directory, or a data_logger experiment directory"
    )
    parser.add_argument("--node", required=True, choices=NODES, help="node core to drive")
    parser.add_argument(
        "--params",
        required=True,
        help="ROS parameter file of the node, e.g. config/lpv_controller.yaml",
    )
    parser.add_argument("--out", required=True, help="output bag directory (must not exist)")
    parser.add_argument("--gains", default=None, help="gains.yaml (overrides gains_file)")
    parser.add_argument("--namespace", default=TOPIC_NAMESPACE, help="topic namespace in the bag")
    parser.add_argument("--storage", default="mcap", choices=("mcap", "sqlite3"))
    parser.add_argument(
        "--ticks",
        default="auto",
        choices=("auto", "recorded", "rate"),
        help="controller tick times: the stamps of the recorded "
        "actuator_command (reproduces the flight exactly), a rate_hz grid "
        "from the first input, or auto (recorded when present)",
    )


def run(args) -> int:
    from lpv_sysid.configuration.parameters import yaml_parameters

    params = yaml_parameters(args.params, args.node)
    if args.gains:
        params["gains_file"] = args.gains
    elif (
        params.get("gains_file")
        and not os.path.isabs(params["gains_file"])
        and not os.path.exists(params["gains_file"])
    ):
        raise ConfigError(
            f"{args.params}: gains_file {params['gains_file']!r} not found (give --gains)"
        )
    s = replay_controller(args.bag, params, args.out, args.namespace, args.storage, args.ticks)
    print(
        f"replayed {s['inputs']} input messages ({s['duration_s']:.2f} s) through "
        f"{args.node} ({s['ticks']} ticks): {s['commands']} actuator commands"
    )
    if s["ticks"] == "state":
        print(
            f"  {s['late_inputs']} input samples arrived after the state sample they were "
            "stamped for (the node counts its own: late_input_count in its status)"
        )
    for topic, n in s["outputs"].items():
        print(f"  {topic}: {n} messages")
    print(f"bound monitor: L2 gain estimate {s['gain_estimate']:.4g} (gamma {s['gamma']:g})")
    print(f"wrote {args.out}")
    ev = s["event"]
    if ev is not None:
        print(
            f"SAFETY ABORT at t={ev.t:.6f} s: {ev.reason}: {ev.detail} -- the controller "
            "would have stopped commanding here"
        )
        return 1
    return 0
