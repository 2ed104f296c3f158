"""`lpv-sysid replay`: drive a node core with the recorded inputs of a bag, write its outputs.

    lpv-sysid replay --bag BAG --node lpv_controller --params config/lpv_controller.yaml \
        --out OUT_BAG [--gains gains.yaml]

The node's message-level runtime (the same code the node runs,
:mod:`lpv_sysid.flight.controller`) receives the bag's input messages in
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

import heapq
import logging
import os
from pathlib import Path
from typing import Any

from lpv_sysid.errors import BagError, ConfigError
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


def bag_directories(path: str) -> list[Path]:
    """The bag directories of ``path``: itself, or ``bag_*`` of an experiment directory."""
    p = Path(path)
    if not p.exists():
        raise BagError(f"--bag {path}: no such file or directory")
    if (p / "metadata.yaml").exists() or p.suffix in (".mcap", ".db3"):
        return [p]
    parts = sorted(d for d in p.glob("bag_*") if d.is_dir())
    if not parts:
        raise BagError(
            f"--bag {path}: neither a rosbag2 directory nor an experiment "
            "directory with bag_NNNN/ parts"
        )
    return parts


def read_inputs(path: str, topics: list[str], optional: str | None = None):
    """``{topic: [(stamp_ns, msg), ...]}`` of every part of ``path`` (sorted by stamp) and
    the stamps of the ``optional`` topic (empty when not recorded)."""
    from lpv_sysid.io.bag import read_bag

    per_topic: dict[str, list[tuple[int, Any]]] = {t: [] for t in topics}
    extra: list[int] = []
    want = topics + ([optional] if optional else [])
    for part in bag_directories(path):
        # only the inputs (and the optional topic) are deserialised, not e.g. imu
        data = read_bag(
            str(part), topics=topics, strict=True, optional=[optional] if optional else ()
        )
        for t in want:
            if t == optional:
                extra.extend(ns for ns, _ in data.get(t, []))
            else:
                per_topic[t].extend(data.get(t, []))
    return {t: sorted(v, key=lambda e: e[0]) for t, v in per_topic.items()}, sorted(extra)


def parsed_stream(topic: str, rel: str, msgs: list) -> list:
    """``[(stamp_ns, rel, payload), ...]`` with payload ``(t, values)`` (batch-parsed), or
    the raw message when the batch holds a malformed one (the runtime then sees it exactly
    as the node would, and aborts at that message)."""
    from lpv_sysid.flight.controller import parse_inputs
    from lpv_sysid.io.messages import MessageError

    try:
        t, values = parse_inputs(rel, [m for _, m in msgs])
    except MessageError:
        return [(ns, rel, m) for ns, m in msgs]
    return [(ns, rel, (t[i], values[i])) for i, (ns, _) in enumerate(msgs)]


def replay_controller(
    bag: str,
    params: dict,
    out: str,
    namespace: str = TOPIC_NAMESPACE,
    storage: str = "mcap",
    ticks: str = "auto",
) -> dict:
    """Run :class:`ControllerRuntime` over the bag; returns a summary dict."""
    from lpv_sysid.flight.controller import INPUT_TOPICS, ControllerRuntime, ControllerSettings
    from lpv_sysid.io.bag import BagWriter
    from lpv_sysid.io.messages import TYPES, MsgFactory

    settings = ControllerSettings.from_dict(params)
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    per_topic, recorded = read_inputs(
        bag, [f"{ns}/{t}" for t in INPUT_TOPICS], f"{ns}/actuator_command"
    )
    inputs = list(
        heapq.merge(
            *[parsed_stream(f"{ns}/{t}", t, per_topic[f"{ns}/{t}"]) for t in INPUT_TOPICS],
            key=lambda e: e[0],
        )
    )
    if ticks == "recorded" and not recorded:
        raise BagError(f"bag {bag}: --ticks recorded needs {ns}/actuator_command in the bag")
    use_recorded = settings.tick_source == "timer" and (
        ticks == "recorded" or (ticks == "auto" and bool(recorded))
    )
    if not inputs:
        raise BagError(f"bag {bag}: the input topics hold no messages")
    rt = ControllerRuntime(settings, MsgFactory.rosbags(), f"{ns}/lpv_controller")
    log = {"info": LOG.info, "warn": LOG.warning, "error": LOG.error}

    def drain():
        for level, text in rt.take_log():
            log[level](text)

    drain()
    period = round(1e9 / settings.rate_hz)
    t0 = inputs[0][0]
    rt.start(t0 * 1e-9)
    outputs = {
        f"{ns}/actuator_command": TYPES["actuator_command"],
        f"{ns}/status": TYPES["status"],
    }
    n_out = {t: 0 for t in outputs}
    if os.path.exists(out):
        raise BagError(f"--out {out}: already exists")
    with BagWriter(out, storage=storage) as w:
        for topic, typ in outputs.items():
            w.add_topic(topic, typ)

        def publish(t_ns, outs):
            for rel, msg in outs:
                w.write(f"{ns}/{rel}", t_ns, msg)
                n_out[f"{ns}/{rel}"] += 1
            drain()

        # the node's timer: the law step (tick_source timer) or only the staleness watch
        # (tick_source state: the law steps on each state sample, below, as in the node).
        # Its times: the recorded command stamps (then the grid continues after them); with
        # tick_source state the recorded commands are the state stamps, so the grid is the rate
        grid = iter(recorded if use_recorded else ())
        state = {"next": next(grid, t0 + period)}

        def advance():
            nxt = next(grid, None)
            state["next"] = nxt if nxt is not None else state["next"] + period

        for stamp, topic, msg in inputs:
            while state["next"] <= stamp:
                publish(state["next"], rt.on_timer(state["next"] * 1e-9))
                advance()
            if isinstance(msg, tuple):
                outs = rt.on_parsed_input(topic, msg[0], msg[1], stamp * 1e-9)
            else:
                outs = rt.on_input(topic, msg, stamp * 1e-9)
            publish(stamp, outs)
        last = inputs[-1][0]  # no tick after the recording ends
        w.write(f"{ns}/status", last, rt.status(last * 1e-9))
        n_out[f"{ns}/status"] += 1
    ev = rt.supervisor.event
    return {
        "inputs": len(inputs),
        "duration_s": (inputs[-1][0] - t0) * 1e-9,
        "outputs": n_out,
        "commands": rt.commands,
        "event": ev,
        "gain_estimate": rt.law.gain(),
        "gamma": rt.law.gamma,
        "ticks": "state"
        if settings.tick_source == "state"
        else ("recorded" if use_recorded else "rate"),
    }


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
