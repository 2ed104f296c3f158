"""Phase-1 recordings as raw time series in core frames (:class:`Streams`): the sources of
:mod:`lpv_sysid.ident.dataprep`.

A rosbag2 directory (via :func:`lpv_sysid.io.bag.read_arrays` and the column
parsers of :mod:`lpv_sysid.io.messages.columns`, so every frame conversion stays in ``io/``) or an
in-memory simulated run (anything with the attributes of ``lpv_sysid.sim.phase1.RunRecord``).
:func:`find_bags` lists the rosbag2 directories of a directory.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lpv_sysid.errors import BagError, ConfigError

log = logging.getLogger(__name__)

TOPICS = ("state", "rotor_speeds", "actuator_command", "velocity_reference", "excitation")


@dataclass(frozen=True)
class Streams:
    """Raw time series of one run in core frames (NED/FRD, SI)."""

    name: str
    t_state: np.ndarray
    euler: np.ndarray  # (N, 3) phi, theta, psi
    v: np.ndarray  # (N, 3)
    omega: np.ndarray  # (N, 3)
    t_rotor: np.ndarray
    Omega: np.ndarray  # (M, 4) rotor speeds, PX4 numbering
    t_cmd: np.ndarray | None = None
    u: np.ndarray | None = None  # (L, 4) virtual actuator command
    t_ref: np.ndarray | None = None
    ref: np.ndarray | None = None  # (R, 4) u_d, v_d, w_d, r_d (FRD)
    t_exc: np.ndarray | None = None
    exc: np.ndarray | None = None  # (E, 4)
    t_excite: float | None = None  # known excitation start (simulation)
    rotor_estimated: bool = False  # rotor_speeds computed from the motor outputs, not measured


# ----------------------------------------------------------------------------- sources
def streams_from_record(rec: Any) -> Streams:
    """Adapter for ``lpv_sysid.sim.phase1.RunRecord`` (measured channels only)."""
    xm = np.asarray(rec.state_meas, dtype=float)
    return Streams(
        name=str(rec.name),
        t_state=np.asarray(rec.state_t, float),
        euler=xm[:, 3:6],
        v=xm[:, 6:9],
        omega=xm[:, 9:12],
        t_rotor=np.asarray(rec.rotor_t, float),
        Omega=np.asarray(rec.rotor_meas, float),
        t_cmd=np.asarray(rec.cmd_t, float),
        u=np.asarray(rec.command, float),
        t_ref=np.asarray(rec.cmd_t, float),
        ref=np.asarray(rec.reference, float),
        t_exc=np.asarray(rec.cmd_t, float),
        exc=np.asarray(rec.excitation, float),
        t_excite=float(rec.t_excite),
    )


def _topic_for(available: Sequence[str], short: str) -> str | None:
    hits = [t for t in available if t.rstrip("/").split("/")[-1] == short]
    if len(hits) > 1:
        raise BagError(f"several topics end in '{short}': {hits}")
    return hits[0] if hits else None


def streams_from_bag(path: str | Path) -> Streams:
    """Read a phase-1 rosbag2 directory (topics of DESIGN.md, any namespace).

    Column-wise: :func:`lpv_sysid.io.bag.read_arrays` (numpy block decode of the records)
    and the column parsers of :mod:`lpv_sysid.io.messages.columns`. A bag whose topics cannot be
    given as columns (messages of one topic with different structure, e.g. channel lists
    of different lengths) or that :func:`read_arrays` refuses is read message by message
    (:func:`lpv_sysid.io.bag.read_bag` and the per-message parsers), which gives the same
    values or names the problem."""
    from lpv_sysid.io import bag as iobag

    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    available = list(iobag.topic_info(str(path)))
    wanted = [t for t in (_topic_for(available, short) for short in TOPICS) if t is not None]
    try:
        data = iobag.read_arrays(str(path), topics=wanted)  # skip imu/status: not needed
    except iobag.UnsafeBagFile:
        raise
    except BagError as exc:
        log.debug("%s: not read column-wise (%s); reading message by message", path, exc)
        return _streams_from_messages(path, wanted)
    return _streams_from_columns(path, data)


def _note_estimated(path: Path) -> None:
    log.warning(
        "%s: rotor_speeds estimated from the motor outputs (seed 0 Eq. 8 with the airframe's "
        "a_Omega, b_Omega): the actuator rows reproduce that model, not a measurement; "
        "a_Omega, b_Omega are not identified from this bag",
        path,
    )


def _streams_from_columns(path: Path, data: Any) -> Streams:
    """:class:`Streams` of the ``{topic: TopicArrays}`` of :func:`read_arrays`."""
    from lpv_sysid.io.messages import columns as cols_of

    def series(short: str, parse, required: bool):
        topic = _topic_for(list(data), short)
        if topic is None or not len(data[topic]):
            if required:
                raise BagError(f"{path}: topic '{short}' missing or empty (have {sorted(data)})")
            return None
        cols = data[topic]
        try:
            return parse(cols)
        except ConfigError as exc:
            row = getattr(exc, "row", None)
            ns = int(cols.log_time[row if row is not None else 0])
            raise BagError(f"{path}: topic '{topic}' at {ns * 1e-9:.3f} s: {exc}") from None

    st = series("state", cols_of.states_from_odometry_columns, True)
    t_rotor, omega = series("rotor_speeds", cols_of.rotor_speeds_from_joint_state_columns, True)
    rotor = data[_topic_for(list(data), "rotor_speeds")]
    estimated = bool(np.any(cols_of.rotor_sources_of_columns(rotor) == "estimated"))
    if estimated:
        _note_estimated(path)
    ac = series("actuator_command", cols_of.actuator_command_from_joint_state_columns, False)
    vr = series("velocity_reference", cols_of.reference_from_twist_columns, False)
    ex = series("excitation", cols_of.excitation_from_joint_state_columns, False)
    kw: dict = {}
    if ac is not None:
        kw["t_cmd"], kw["u"] = ac
    if vr is not None:
        kw["t_ref"] = vr[0]
        kw["ref"] = np.column_stack([vr[1], vr[2]])
    if ex is not None:
        kw["t_exc"], kw["exc"] = ex
    return Streams(
        name=path.name,
        t_state=st.t,
        euler=st.euler,
        v=st.v_body,
        omega=st.omega,
        t_rotor=t_rotor,
        Omega=omega,
        rotor_estimated=estimated,
        **kw,
    )


def _streams_from_messages(path: Path, wanted: Sequence[str]) -> Streams:
    """:class:`Streams` through :func:`read_bag` and the per-message parsers."""
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io import messages as msgs

    data = iobag.read_bag(str(path), topics=wanted)

    def series(short, parse, required):
        topic = _topic_for(list(data), short)
        if topic is None or not data[topic]:
            if required:
                raise BagError(f"{path}: topic '{short}' missing or empty (have {sorted(data)})")
            return None
        rows = []
        for stamp_ns, msg in data[topic]:
            try:
                rows.append(parse(msg))
            except ConfigError as exc:
                raise BagError(
                    f"{path}: topic '{topic}' at {stamp_ns * 1e-9:.3f} s: {exc}"
                ) from None
        return rows

    st = series("state", msgs.state_from_odometry, True)
    rs = series("rotor_speeds", msgs.rotor_speeds_from_joint_state, True)
    estimated = any(
        msgs.rotor_source_of(m) == "estimated"
        for _, m in data[_topic_for(list(data), "rotor_speeds")]
    )
    if estimated:
        _note_estimated(path)
    ac = series("actuator_command", msgs.actuator_command_from_joint_state, False)
    vr = series("velocity_reference", msgs.reference_from_twist, False)
    ex = series("excitation", msgs.excitation_from_joint_state, False)
    kw: dict = {}
    if ac:
        kw["t_cmd"] = np.array([r[0] for r in ac])
        kw["u"] = np.array([r[1] for r in ac])
    if vr:
        kw["t_ref"] = np.array([r[0] for r in vr])
        kw["ref"] = np.array([[*r[1], r[2]] for r in vr])
    if ex:
        kw["t_exc"] = np.array([r[0] for r in ex])
        kw["exc"] = np.array([r[1] for r in ex])
    return Streams(
        name=path.name,
        t_state=np.array([s.t for s in st]),
        euler=np.array([s.euler for s in st]),
        v=np.array([s.v_body for s in st]),
        omega=np.array([s.omega for s in st]),
        t_rotor=np.array([r[0] for r in rs]),
        Omega=np.array([r[1] for r in rs]),
        rotor_estimated=estimated,
        **kw,
    )


def find_bags(directory: str | Path) -> list[Path]:
    """rosbag2 directories (containing metadata.yaml) directly under ``directory``, sorted."""
    d = Path(directory)
    if not d.is_dir():
        raise BagError(f"{d}: not a directory")
    bags = sorted(p for p in d.iterdir() if p.is_dir() and (p / "metadata.yaml").exists())
    if not bags:
        raise BagError(f"{d}: no rosbag2 directories (with metadata.yaml) found")
    return bags
