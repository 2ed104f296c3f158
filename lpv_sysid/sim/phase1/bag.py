"""Phase-1 runs as rosbag2 directories with the topics of docs/DESIGN.md, built in bulk from
the run's arrays (the :mod:`lpv_sysid.io.messages` builders as the reference)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from lpv_sysid.io.messages import TOPIC_NAMESPACE
from lpv_sysid.sim.phase1.runs import RunRecord

log = logging.getLogger(__name__)

BAG_TOPICS = ("state", "rotor_speeds", "imu", "velocity_reference", "actuator_command", "status")


#: the declared epoch of simulated runs (``simulate phase1 --epoch``): 2026-01-01T00:00:00Z,
#: so the bags open at a plausible date in Foxglove / PlotJuggler and say they are simulated
DECLARED_EPOCH_NS = 1_767_225_600 * 1_000_000_000


def write_run_bag(
    record: RunRecord,
    path: str | Path,
    storage: str = "mcap",
    namespace: str = TOPIC_NAMESPACE,
    epoch_ns: int = 0,
) -> Path:
    """Write one run as a rosbag2 directory with the topics of docs/DESIGN.md.

    Topics (``namespace``/name): ``state`` (estimator output), ``rotor_speeds``, ``imu``
    (orientation from the nearest estimator sample), ``velocity_reference``,
    ``actuator_command`` and ``status`` (1 Hz, phase trim/excitation). Messages are those
    of the :mod:`lpv_sysid.io.messages` builders (frame conversions by
    :mod:`lpv_sysid.io.frames`), written by :class:`lpv_sysid.io.bag.BagWriter`; stamps are
    ``epoch_ns`` + nanoseconds from the run start (``simulate phase1`` declares
    :data:`DECLARED_EPOCH_NS`), messages in stamp order.

    The arrays are complete, so every topic is built in bulk: one builder message is the
    template, the frame conversions run on whole arrays and the CDR records come from
    :func:`lpv_sysid.io.bag.encode_block` (:func:`_bulk_rows`; first, middle and last record
    of each topic checked against the builder). A record the builders would reject (a
    non-finite value, a stamp beyond int32 seconds) sends the run through the builders
    message by message, which name the offending field.
    """
    from lpv_sysid.errors import BagError

    try:
        from lpv_sysid.io import messages
        from lpv_sysid.io.bag import BagWriter
    except ImportError as exc:
        raise BagError(f"{path}: rosbag2 writing unavailable ({exc})") from None
    f = messages.MsgFactory.rosbags()
    path = Path(path)
    topic = {name: f"{namespace}/{name}" for name in BAG_TOPICS}
    rows = _bulk_rows(record, f, topic, int(epoch_ns))
    try:
        with BagWriter(str(path), storage=storage) as w:
            for name in BAG_TOPICS:
                w.add_topic(topic[name], messages.TYPES[name], messages.qos_of(name))
            if rows is not None:
                w.write_many(rows)
            else:
                for stamp, name, msg in _message_items(record, f, int(epoch_ns)):
                    w.write(topic[name], stamp, msg)
    except BagError:
        raise
    except OSError as exc:
        raise BagError(f"{path}: cannot write bag ({exc})") from None
    return path


def _stamp_ns(t) -> int:
    return int(round(float(t) * 1e9))


def _status_items(record: RunRecord, f, epoch_ns: int = 0) -> list:
    from lpv_sysid.io import messages

    items = []
    for t in np.arange(0.0, record.duration, 1.0):
        phase = "trim" if t < record.t_excite else "excitation"
        st = messages.diagnostic_status(
            f,
            "OK",
            "sim_phase1",
            f"{record.name}: {phase}",
            {
                "phase": phase,
                "run": record.name,
                "v_d": " ".join(f"{c:g}" for c in record.v_d),
                "t_excite": record.t_excite,
                "seed": record.meta.get("seed", ""),
            },
        )
        st_ns = _stamp_ns(t) + epoch_ns
        items.append((st_ns, "status", messages.diagnostic_array(f, st_ns, [st])))
    return items


def _imu_state_index(record: RunRecord) -> np.ndarray:
    """Index of the estimator sample whose attitude each IMU message carries."""
    return np.clip(
        np.searchsorted(record.state_t, record.imu_t, side="right") - 1, 0, len(record.state_t) - 1
    )


def _message_items(record: RunRecord, f, epoch_ns: int = 0) -> list:
    """(stamp_ns, topic name, message) of every message, built one at a time, stamp order."""
    from lpv_sysid.io import messages

    def ns(t) -> int:
        return _stamp_ns(t) + epoch_ns

    items: list[tuple[int, str, Any]] = []
    xm = record.state_meas
    for t, x in zip(record.state_t, xm):
        items.append(
            (
                ns(t),
                "state",
                messages.odometry_from_state(f, ns(t), x[0:3], x[3:6], x[6:9], x[9:12]),
            )
        )
    for t, om in zip(record.rotor_t, record.rotor_meas):
        items.append((ns(t), "rotor_speeds", messages.rotor_speeds_msg(f, ns(t), om)))
    for t, a, w, i in zip(
        record.imu_t, record.imu_accel, record.imu_gyro, _imu_state_index(record)
    ):
        items.append((ns(t), "imu", messages.imu_msg(f, ns(t), a, w, xm[i, 3:6])))
    for t, r, u in zip(record.cmd_t, record.reference, record.command):
        items.append(
            (
                ns(t),
                "velocity_reference",
                messages.twist_reference_msg(f, ns(t), r[0:3], float(r[3])),
            )
        )
        items.append((ns(t), "actuator_command", messages.actuator_command_msg(f, ns(t), u)))
    items.extend(_status_items(record, f, epoch_ns))
    items.sort(key=lambda it: it[0])
    return items


def _bulk_rows(record: RunRecord, f, topic: Mapping[str, str], epoch_ns: int = 0):
    """``(topic, stamp_ns, CDR record)`` of every message of :func:`write_run_bag` in the order
    of :func:`_message_items`, built per topic with :func:`lpv_sysid.io.bag.encode_block`;
    None when a sample would be rejected by the builders or a record disagrees with them."""
    from lpv_sysid.io import frames, messages
    from lpv_sysid.io.bag import jazzy_typestore
    from lpv_sysid.io.bag.cdr import LayoutError, encode_block, records_close

    def stamps(t):
        t = np.asarray(t, dtype=float)
        if t.size == 0 or not np.all(np.isfinite(t)):
            return None
        ns = np.round(t * 1e9).astype(np.int64) + np.int64(epoch_ns)
        sec, nsec = np.divmod(ns, 1_000_000_000)
        if sec.min() < -(2**31) or sec.max() > 2**31 - 1:
            return None
        return ns, {"header.stamp.sec": sec, "header.stamp.nanosec": nsec}

    xm = np.asarray(record.state_meas, dtype=float)
    cols = {
        "state": (record.state_t, [xm[:, 0:12]]),
        "rotor_speeds": (record.rotor_t, [record.rotor_meas]),
        "imu": (record.imu_t, [record.imu_accel, record.imu_gyro]),
        "velocity_reference": (record.cmd_t, [record.reference]),
        "actuator_command": (record.cmd_t, [record.command]),
    }
    blocks = {}
    try:
        for name, (t, arrays) in cols.items():
            st = stamps(t)
            if st is None or not all(np.all(np.isfinite(a)) for a in arrays):
                return None
            blocks[name] = st
        ii = _imu_state_index(record)
        e = xm[:, 3:6]
        pos, q = frames.ned_to_enu(xm[:, 0:3]), frames.ros_orientation_from_euler(e)
        v, w = frames.frd_to_flu(xm[:, 6:9]), frames.frd_to_flu(xm[:, 9:12])
        acc, gyr = frames.frd_to_flu(record.imu_accel), frames.frd_to_flu(record.imu_gyro)
        ref = np.asarray(record.reference, dtype=float)
        vref = frames.frd_to_flu(ref[:, 0:3])
        wref = frames.frd_to_flu(
            np.column_stack([np.zeros(len(ref)), np.zeros(len(ref)), ref[:, 3]])
        )

        def xyz(prefix, a):
            return {f"{prefix}.x": a[:, 0], f"{prefix}.y": a[:, 1], f"{prefix}.z": a[:, 2]}

        def quat(prefix, a):
            return {**xyz(prefix, a), f"{prefix}.w": a[:, 3]}

        k0 = 0
        templates: dict[str, tuple[Any, Any, dict]] = {
            "state": (
                messages.odometry_from_state,
                lambda k: (xm[k, 0:3], xm[k, 3:6], xm[k, 6:9], xm[k, 9:12]),
                {
                    **xyz("pose.pose.position", pos),
                    **quat("pose.pose.orientation", q),
                    **xyz("twist.twist.linear", v),
                    **xyz("twist.twist.angular", w),
                },
            ),
            "rotor_speeds": (
                messages.rotor_speeds_msg,
                lambda k: (record.rotor_meas[k],),
                {"velocity": np.asarray(record.rotor_meas, dtype=float)},
            ),
            "imu": (
                messages.imu_msg,
                lambda k: (record.imu_accel[k], record.imu_gyro[k], xm[ii[k], 3:6]),
                {
                    **quat("orientation", q[ii]),
                    **xyz("angular_velocity", gyr),
                    **xyz("linear_acceleration", acc),
                },
            ),
            "velocity_reference": (
                messages.twist_reference_msg,
                lambda k: (ref[k, 0:3], float(ref[k, 3])),
                {**xyz("twist.linear", vref), **xyz("twist.angular", wref)},
            ),
            "actuator_command": (
                messages.actuator_command_msg,
                lambda k: (record.command[k],),
                {"position": np.asarray(record.command, dtype=float)},
            ),
        }
        ts = jazzy_typestore()
        data = {}
        for name, (build, args, values) in templates.items():
            ns, head = blocks[name]
            msgtype = messages.TYPES[name]
            block = encode_block(
                msgtype, build(f, int(ns[k0]), *args(k0)), {**head, **values}, len(ns), ts
            )
            for k in sorted({0, len(ns) // 2, len(ns) - 1}):  # the builders agree?
                ref_k = bytes(ts.serialize_cdr(build(f, int(ns[k]), *args(k)), msgtype))
                if not records_close(
                    msgtype, block[k], ref_k, rtol=1e-14, atol=1e-15, typestore=ts
                ):
                    log.warning(
                        "run %s: bulk %s record %d disagrees with io.messages; writing "
                        "message by message",
                        record.name,
                        name,
                        k,
                    )
                    return None
            data[name] = (ns, block)
    except (LayoutError, messages.MessageError, ValueError) as exc:
        log.warning(
            "run %s: bulk bag writing unavailable (%s); writing message by message",
            record.name,
            exc,
        )
        return None
    status = [
        (ns, "status", bytes(ts.serialize_cdr(msg, messages.TYPES["status"])))
        for ns, _, msg in _status_items(record, f, epoch_ns)
    ]
    # the order of _message_items: stamp, then state, rotor, imu, (reference, command) per
    # control sample, status
    ns_c = data["velocity_reference"][0]
    parts = [
        ("state", data["state"][0]),
        ("rotor_speeds", data["rotor_speeds"][0]),
        ("imu", data["imu"][0]),
    ]
    names = [np.full(len(a), i, np.int8) for i, (_, a) in enumerate(parts)]
    idx = [np.arange(len(a)) for _, a in parts]
    stamps_ = [a for _, a in parts]
    stamps_.append(np.repeat(ns_c, 2))
    names.append(np.tile(np.array([3, 4], np.int8), len(ns_c)))
    idx.append(np.repeat(np.arange(len(ns_c)), 2))
    stamps_.append(np.array([s for s, _, _ in status], np.int64))
    names.append(np.full(len(status), 5, np.int8))
    idx.append(np.arange(len(status)))
    all_ns, all_name, all_idx = np.concatenate(stamps_), np.concatenate(names), np.concatenate(idx)
    order = np.argsort(all_ns, kind="stable")
    src = [
        data["state"][1],
        data["rotor_speeds"][1],
        data["imu"][1],
        data["velocity_reference"][1],
        data["actuator_command"][1],
        [d for _, _, d in status],
    ]
    tnames = [
        topic[n]
        for n in (
            "state",
            "rotor_speeds",
            "imu",
            "velocity_reference",
            "actuator_command",
            "status",
        )
    ]
    return [
        (tnames[c], s, src[c][i])
        for s, c, i in zip(
            all_ns[order].tolist(), all_name[order].tolist(), all_idx[order].tolist()
        )
    ]
