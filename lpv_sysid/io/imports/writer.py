"""A :class:`FlightRecord` -> one rosbag2 per run in the package's own topics and types,
written by the data logger's :class:`~lpv_sysid.io.recorder.Recorder` (the same layout as
``lpv-sysid fly phase1``: ``DIR/bag_NNNN`` + ``DIR/experiment.yaml``), so ``identify`` reads
an imported flight unchanged. The provenance of the source goes into ``experiment.yaml``
(``provenance``: source, vehicle kind, firmware, airframe, parameters, battery, clock,
the runs with their windows on the source's clock)."""

from __future__ import annotations

import heapq
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from lpv_sysid.io.imports.record import FlightRecord, Run

log = logging.getLogger(__name__)

TOPICS = ("state", "imu", "rotor_speeds", "velocity_reference", "rate_setpoint", "status")


@dataclass(frozen=True)
class ImportedRun:
    """One written run: its name, bag directory (relative to the output) and counts."""

    name: str
    bag: str
    start: float
    end: float
    messages: int


def _stream(name: str, stamps: np.ndarray, idx: np.ndarray, make: Callable):
    for k in idx:
        yield int(stamps[k]), name, int(k), make


def write_runs(
    rec: FlightRecord,
    runs: Sequence[Run],
    out_dir: str | Path,
    storage: str = "mcap",
) -> list[ImportedRun]:
    """Write ``runs`` of ``rec`` under ``out_dir`` (it must not exist or be empty)."""
    from lpv_sysid.io import messages as m
    from lpv_sysid.io.recorder import Recorder, RecorderConfig
    from lpv_sysid.mavlink.bridge import RATE_INPUT_NAMES

    f = m.MsgFactory.rosbags()
    ns = m.TOPIC_NAMESPACE
    types = {n: m.TYPES.get(n, m.TYPES["actuator_command"]) for n in TOPICS}
    recorder = Recorder(
        RecorderConfig(
            out_dir=str(out_dir),
            topics={f"{ns}/{n}": types[n] for n in TOPICS},
            storage=storage,
            description=f"imported from {rec.source}",
        )
    )
    s = rec.state
    makers: dict[str, tuple[np.ndarray, Callable[[int, int], Any]]] = {
        "state": (
            s.t,
            lambda st, k: m.odometry_from_state(
                f, st, s.pos_ned[k], s.euler[k], s.v_body[k], s.omega[k]
            ),
        )
    }
    if rec.imu is not None:
        imu = rec.imu
        makers["imu"] = (imu.t, lambda st, k: m.imu_msg(f, st, imu.y[k, :3], imu.y[k, 3:6]))
    if rec.rotors is not None:
        rot, src = rec.rotors, rec.rotor_source
        makers["rotor_speeds"] = (rot.t, lambda st, k: m.rotor_speeds_msg(f, st, rot.y[k], src))
    if rec.reference is not None:
        ref = rec.reference
        makers["velocity_reference"] = (
            ref.t,
            lambda st, k: m.twist_reference_msg(f, st, ref.y[k, :3], float(ref.y[k, 3])),
        )
    if rec.rate_setpoint is not None:
        rs = rec.rate_setpoint
        makers["rate_setpoint"] = (
            rs.t,
            lambda st, k: m.joint_state(f, st, RATE_INPUT_NAMES, position=rs.y[k]),
        )
    if rec.events:
        ev = rec.events
        makers["status"] = (
            np.array([e.t for e in ev]),
            lambda st, k: m.diagnostic_array(
                f,
                st,
                [m.diagnostic_status(f, ev[k].level, "px4", ev[k].message, ev[k].values)],
            ),
        )
    written: list[ImportedRun] = []
    t0 = min(r.start for r in runs)
    recorder.start(int(rec.stamps_ns(np.array([t0]))[0]))
    try:
        for run in runs:
            bag = recorder.split()
            n = 0
            for st, topic, k, make in _merged(makers, run, rec):
                recorder.record(f"{ns}/{topic}", st, make(st, k))
                n += 1
            written.append(ImportedRun(run.name, bag, run.start, run.end, n))
            log.info("%s: run %s -> %s (%d messages)", rec.source, run.name, bag, n)
        recorder.annotate("provenance", provenance(rec, written))
    finally:
        recorder.stop(int(rec.stamps_ns(np.array([max(r.end for r in runs)]))[0]))
    return written


def _merged(makers, run: Run, rec: FlightRecord) -> Iterator[tuple[int, str, int, Any]]:
    streams = []
    for name, (t, make) in makers.items():
        idx = np.nonzero((t >= run.start) & (t <= run.end))[0]
        streams.append(_stream(name, rec.stamps_ns(t), idx, make))
    return heapq.merge(*streams, key=lambda r: r[0])


def provenance(rec: FlightRecord, runs: Sequence[ImportedRun]) -> dict:
    """The ``provenance`` entry of ``experiment.yaml`` for an imported flight."""
    return {
        **rec.provenance,
        "vehicle_kind": rec.provenance.get("vehicle_kind", "UNKNOWN"),
        "clock": {
            "kind": rec.clock,
            "offset_ns": int(rec.clock_offset_ns),
            "rate": float(rec.clock_rate),
            "knots": None if rec.clock_knots is None else len(rec.clock_knots[0]),
            "meaning": "bag stamp [ns] = t * 1e9 * rate + offset_ns (or + the offset interpolated "
            "in the recording's px4_clock knots); t [s]: since PX4 boot (ULog, "
            "px4_msgs) or since the first odometry message (MAVROS)",
        },
        "rotor_speeds": rec.rotor_source if rec.rotors is not None else None,
        "offboard_segments": [[round(a, 6), round(b, 6)] for a, b in rec.offboard],
        "runs": [
            {
                "name": r.name,
                "bag": r.bag,
                "window_s": [round(r.start, 6), round(r.end, 6)],
                "messages": r.messages,
            }
            for r in runs
        ],
        "notes": list(rec.notes),
    }


def import_flight(
    rec: FlightRecord,
    out_dir: str | Path,
    windows: Sequence[str] = (),
    storage: str = "mcap",
    min_duration: float = 1.0,
    vehicle_kind: str | None = None,
) -> list[ImportedRun]:
    """Split ``rec`` into runs (:func:`~lpv_sysid.io.imports.record.runs_of`) and write them
    (:func:`write_runs`); ``vehicle_kind`` overrides the kind read from the source."""
    from lpv_sysid.io.imports.record import runs_of

    if vehicle_kind is not None:
        rec.provenance["vehicle_kind"] = vehicle_kind
    return write_runs(rec, runs_of(rec, windows, min_duration), out_dir, storage)
