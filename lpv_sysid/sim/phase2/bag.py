"""rosbag2 recording of the phase-2 nonlinear flight (run b) with the DESIGN.md topics.

:class:`Phase2Bag` is the :class:`lpv_sysid.sim.phase2.flight.BagSink` of the product. It keeps
the samples of the flight as arrays and writes them in blocks: every topic of a block is
encoded at once by :func:`lpv_sysid.io.bag.encode_block` from one :mod:`lpv_sysid.io.messages`
builder message (the template; the frame conversions of :mod:`lpv_sysid.io.frames` run on whole
arrays) and the records go to :meth:`lpv_sysid.io.bag.BagWriter.write_many` in the order the
flight produced them -- per control sample ``state, rotor_speeds, imu, velocity_reference,
excitation, actuator_command``, the ``status`` messages where they were emitted. The first,
middle and last record of every topic of a block are checked against the builders; a block the
builders would reject (a non-finite value, a stamp beyond int32 seconds) or that disagrees with
them is written message by message through the builders, which name the offending field.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from lpv_sysid.errors import BagError
from lpv_sysid.io.messages import TOPIC_NAMESPACE

log = logging.getLogger(__name__)

#: the topics of one control sample, in the order they are written
SAMPLE_TOPICS = (
    "state",
    "rotor_speeds",
    "imu",
    "velocity_reference",
    "excitation",
    "actuator_command",
)
BAG_TOPICS = SAMPLE_TOPICS + ("status",)
#: the arrays kept per sample (columns of :meth:`Phase2Bag.sample`)
_COLUMNS = ("x", "accel", "gyro", "omega", "v_d", "ue", "u")


class Phase2Bag:
    """rosbag2 (mcap or sqlite3) recorder of run (b) (module docstring).

    Stamps are nanoseconds from the run start; ``excitation`` carries the normalised u_e
    (DESIGN.md), kappa is in every ``status``. The samples are written every ``flush_every``
    control samples and on close. Use as a context manager: the pending samples are written and
    the bag is closed (and stays readable) also after an error. ``counts`` holds the messages
    written per topic.
    """

    def __init__(
        self,
        path: str | Path,
        storage: str = "mcap",
        namespace: str = TOPIC_NAMESPACE,
        node_name: str = "sim_phase2",
        kappa: float = 1.0,
        flush_every: int = 500,
    ) -> None:
        from lpv_sysid.io import messages
        from lpv_sysid.io.bag import BagWriter

        self.messages = messages
        self.f = messages.MsgFactory.rosbags()
        self.path = Path(path)
        self.node_name = node_name
        self.kappa = float(kappa)
        self.flush_every = max(1, int(flush_every))
        self.topic = {name: f"{namespace}/{name}" for name in BAG_TOPICS}
        self.writer = BagWriter(str(self.path), storage=storage)
        self.counts = {name: 0 for name in BAG_TOPICS}
        self._t: list[float] = []
        self._cols: dict[str, list[np.ndarray]] = {c: [] for c in _COLUMNS}
        # one entry per message group in flight order: None = the next sample, else a status
        self._events: list[Optional[tuple[int, Any]]] = []

    def __enter__(self) -> "Phase2Bag":
        self.writer.open()
        for name in BAG_TOPICS:
            self.writer.add_topic(
                self.topic[name], self.messages.TYPES[name], self.messages.qos_of(name)
            )
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is None:
                self.flush()
            else:
                try:
                    self.flush()  # what was flown before the error
                except Exception as flush_exc:  # noqa: BLE001 - the first error is the one raised
                    log.error("%s: pending samples not written (%s)", self.path, flush_exc)
        except BaseException as err:
            self.writer.__exit__(type(err), err, err.__traceback__)
            raise
        return self.writer.__exit__(exc_type, exc, tb)

    # ------------------------------------------------------------------ BagSink
    def sample(self, t, x16_meas, imu, Omega_meas, v_d, ue, u) -> None:
        c = self._cols
        c["x"].append(np.array(x16_meas[:12], dtype=float))
        c["accel"].append(np.array(imu[0], dtype=float))
        c["gyro"].append(np.array(imu[1], dtype=float))
        c["omega"].append(np.array(Omega_meas, dtype=float))
        c["v_d"].append(np.array(v_d, dtype=float))
        c["ue"].append(np.array(ue, dtype=float))
        c["u"].append(np.array(u, dtype=float))
        self._t.append(float(t))
        self._events.append(None)
        if len(self._t) >= self.flush_every:
            self.flush()

    def status(self, t, level, message, values) -> None:
        messages, f, ns = self.messages, self.f, _stamp_ns(t)
        vals = {"phase": "phase2", "kappa": self.kappa}
        vals.update(values)
        st = messages.diagnostic_status(f, level, self.node_name, message, vals)
        self._events.append((ns, messages.diagnostic_array(f, ns, [st])))

    # ------------------------------------------------------------------ writing
    def flush(self) -> int:
        """Write the pending samples and statuses; returns the number of messages written."""
        if not self._events:
            return 0
        t = np.array(self._t, dtype=float)
        cols = {k: np.array(v, dtype=float).reshape(len(t), -1) for k, v in self._cols.items()}
        events = self._events
        self._t, self._events = [], []
        self._cols = {c: [] for c in _COLUMNS}
        rows = self._rows(t, cols, events)
        n = self.writer.write_many(rows)
        for name, _, _ in rows:
            self.counts[name.rsplit("/", 1)[-1]] += 1
        return n

    def _rows(self, t: np.ndarray, cols: dict[str, np.ndarray], events: list) -> list:
        """``(topic, stamp_ns, CDR record)`` of the pending messages in flight order."""
        ts = self.writer.typestore
        status_type = self.messages.TYPES["status"]
        try:
            statuses = [ts.serialize_cdr(ev[1], status_type) for ev in events if ev is not None]
        except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds
            raise BagError(f"bag {self.path}: cannot serialise a status message ({exc})") from None
        ns = np.round(t * 1e9).astype(np.int64)
        blocks = _bulk_blocks(self.messages, self.f, ts, ns, cols, self.kappa) if t.size else {}
        if t.size and blocks is None:
            blocks = self._builder_records(ns, cols)
        names = [self.topic[n] for n in SAMPLE_TOPICS]
        per_topic = [blocks[n] for n in SAMPLE_TOPICS] if t.size else []
        rows: list = []
        k = s = 0
        status_topic = self.topic["status"]
        for ev in events:
            if ev is None:
                stamp = int(ns[k])
                rows.extend((names[j], stamp, per_topic[j][k]) for j in range(len(names)))
                k += 1
            else:
                rows.append((status_topic, ev[0], statuses[s]))
                s += 1
        return rows

    def _builder_records(self, ns: np.ndarray, cols: dict[str, np.ndarray]) -> dict[str, list]:
        """The records of every sample built one message at a time by the io.messages builders
        (they raise :class:`lpv_sysid.io.messages.MessageError` naming a non-finite field)."""
        ts, messages, f = self.writer.typestore, self.messages, self.f
        out: dict[str, list] = {n: [] for n in SAMPLE_TOPICS}
        for k, stamp in enumerate(ns.tolist()):
            for name, (build, args) in _builders(messages, cols, self.kappa).items():
                msg = build(f, stamp, *args(k))
                out[name].append(bytes(ts.serialize_cdr(msg, messages.TYPES[name])))
        return out


def _stamp_ns(t) -> int:
    return int(round(float(t) * 1e9))


def _builders(
    messages, cols: dict[str, np.ndarray], kappa: float
) -> dict[str, tuple[Callable, Callable]]:
    """Per sample topic: the io.messages builder and its arguments for sample k (after f, ns)."""
    x = cols["x"]
    return {
        "state": (
            messages.odometry_from_state,
            lambda k: (x[k, 0:3], x[k, 3:6], x[k, 6:9], x[k, 9:12]),
        ),
        "rotor_speeds": (messages.rotor_speeds_msg, lambda k: (cols["omega"][k],)),
        "imu": (messages.imu_msg, lambda k: (cols["accel"][k], cols["gyro"][k], x[k, 3:6])),
        "velocity_reference": (messages.twist_reference_msg, lambda k: (cols["v_d"][k], 0.0)),
        "excitation": (messages.excitation_msg, lambda k: (cols["ue"][k] / kappa,)),
        "actuator_command": (messages.actuator_command_msg, lambda k: (cols["u"][k],)),
    }


def _bulk_blocks(messages, f, ts, ns: np.ndarray, cols: dict[str, np.ndarray], kappa: float):
    """Per sample topic the (n, size) uint8 CDR block of :func:`lpv_sysid.io.bag.encode_block`,
    or None when a value would be rejected by the builders or a record disagrees with them."""
    from lpv_sysid.io import frames
    from lpv_sysid.io.bag.cdr import LayoutError, encode_block, records_close

    if not all(np.all(np.isfinite(a)) for a in cols.values()):
        return None
    sec, nsec = np.divmod(ns, 1_000_000_000)
    if sec.min() < 0 or sec.max() > 2**31 - 1:
        return None
    head = {"header.stamp.sec": sec, "header.stamp.nanosec": nsec}
    x = cols["x"]
    q = frames.ros_orientation_from_euler(x[:, 3:6])

    def xyz(prefix: str, a: np.ndarray) -> dict:
        return {f"{prefix}.x": a[:, 0], f"{prefix}.y": a[:, 1], f"{prefix}.z": a[:, 2]}

    def quat(prefix: str) -> dict:
        return {**xyz(prefix, q), f"{prefix}.w": q[:, 3]}

    values = {
        "state": {
            **xyz("pose.pose.position", frames.ned_to_enu(x[:, 0:3])),
            **quat("pose.pose.orientation"),
            **xyz("twist.twist.linear", frames.frd_to_flu(x[:, 6:9])),
            **xyz("twist.twist.angular", frames.frd_to_flu(x[:, 9:12])),
        },
        "rotor_speeds": {"velocity": cols["omega"]},
        "imu": {
            **quat("orientation"),
            **xyz("angular_velocity", frames.frd_to_flu(cols["gyro"])),
            **xyz("linear_acceleration", frames.frd_to_flu(cols["accel"])),
        },
        "velocity_reference": xyz("twist.linear", frames.frd_to_flu(cols["v_d"])),
        "excitation": {"position": cols["ue"] / kappa},
        "actuator_command": {"position": cols["u"]},
    }
    n = len(ns)
    out = {}
    try:
        for name, (build, args) in _builders(messages, cols, kappa).items():
            msgtype = messages.TYPES[name]
            block = encode_block(
                msgtype, build(f, int(ns[0]), *args(0)), {**head, **values[name]}, n, ts
            )
            for k in sorted({0, n // 2, n - 1}):  # the builders agree?
                want = bytes(ts.serialize_cdr(build(f, int(ns[k]), *args(k)), msgtype))
                if not records_close(
                    msgtype, block[k], want, rtol=1e-14, atol=1e-15, typestore=ts
                ):
                    log.warning(
                        "phase-2 bag: bulk %s record %d disagrees with io.messages; writing "
                        "message by message",
                        name,
                        k,
                    )
                    return None
            out[name] = block
    except (LayoutError, messages.MessageError, ValueError) as exc:
        log.warning("phase-2 bag: bulk writing unavailable (%s); writing message by message", exc)
        return None
    return out
