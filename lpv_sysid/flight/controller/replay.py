"""A recorded flight replayed through the controller's runtime (`lpv-sysid replay`).

:class:`~lpv_sysid.flight.controller.runtime.ControllerRuntime` (the code the node runs)
receives the bag's input messages in timestamp order (bag receive time) and its timer ticks
at ``rate_hz`` on the bag's clock; what it would have published (``actuator_command``,
abort ``status``) is written to a new bag. Ticks follow the node's ``tick_source``: ``timer``
steps the law at each timer tick (the recorded command stamps when the bag has them, then a
``rate_hz`` grid), ``state`` on each new state sample at its stamp while the timer only
judges staleness; with ``state`` the law sees each input by its stamp (the newest sample
stamped at or before the state sample), so a command differs from the node's only where a
sample arrived after the state it was stamped for at the node and not at the logger, or the
reverse (both count them: ``late_input_count`` in the node's status, ``late_inputs`` here).
The runtime is started as the node starts it: at the first input
message after which every input stream has delivered a sample (``start`` with
``wait_for_inputs``; a bag recorded before the vehicle's state flowed does not start the
law on references alone); the parameters go through
:class:`~lpv_sysid.flight.controller.settings.ControllerSettings` and the gains through the
start-up checks, so what the node refuses is refused here too.
"""

from __future__ import annotations

import heapq
import logging
import os
from pathlib import Path
from typing import Any

from lpv_sysid.errors import BagError
from lpv_sysid.flight.controller.messages import INPUT_TOPICS, parse_inputs
from lpv_sysid.flight.controller.runtime import ControllerRuntime
from lpv_sysid.flight.controller.settings import ControllerSettings
from lpv_sysid.io.messages import TOPIC_NAMESPACE

LOG = logging.getLogger(__name__)


def bag_directories(path: str) -> list[Path]:
    """The bag directories of ``path``: itself, or ``bag_*`` of an experiment directory."""
    p = Path(path)
    if not p.exists():
        raise BagError(f"bag {path}: no such file or directory")
    if (p / "metadata.yaml").exists() or p.suffix in (".mcap", ".db3"):
        return [p]
    parts = sorted(d for d in p.glob("bag_*") if d.is_dir())
    if not parts:
        raise BagError(
            f"bag {path}: neither a rosbag2 directory nor an experiment "
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
        raise BagError(f"bag {bag}: ticks 'recorded' need {ns}/actuator_command in the bag")
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
    started = False
    outputs = {
        f"{ns}/actuator_command": TYPES["actuator_command"],
        f"{ns}/status": TYPES["status"],
    }
    n_out = {t: 0 for t in outputs}
    if os.path.exists(out):
        raise BagError(f"output bag {out}: already exists")
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
            if not started:  # as the node: started once every input stream has arrived
                started, _ = rt.start(stamp * 1e-9, wait_for_inputs=True)
        last = inputs[-1][0]  # no tick after the recording ends
        w.write(f"{ns}/status", last, rt.status(last * 1e-9))
        n_out[f"{ns}/status"] += 1
    ev = rt.supervisor.event
    return {
        "inputs": len(inputs),
        "duration_s": (inputs[-1][0] - t0) * 1e-9,
        "outputs": n_out,
        "commands": rt.commands,
        "late_inputs": rt.late_inputs,
        "event": ev,
        "gain_estimate": rt.law.gain(),
        "gamma": rt.law.gamma,
        "ticks": "state"
        if settings.tick_source == "state"
        else ("recorded" if use_recorded else "rate"),
    }
