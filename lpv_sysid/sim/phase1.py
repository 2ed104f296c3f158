"""Phase-1 experiment simulation (seed 0 Sec. IV): vertex flights under baseline control.

For each vertex v_d of the scheduling box (seed 0 Eq. 20, default [-5, 5]^3 m/s, Table 1
order: u fastest, then v, then w) the simulated vehicle flies ``trim_s`` (10 s) at the
constant body-velocity reference, then ``excite_s`` (30 s) of a 4-axis multisine on the
u, v, w and yaw-rate references (0.2-2 Hz), all under the PX4-like baseline controller.
One extra run about hover serves as the independent validation manoeuvre.

With ``start: hover`` (default) each run starts in hover (model hover trim, controller
integrators warm started there) and the vertex reference is applied as a step at t = 0,
so the 10 s trim segment contains the transition and the settling, as in flight; with
``start: trim`` the run starts at the model trim of its vertex (quick tests). The
achieved equilibrium is the mean over the last ``trim_average_s`` of the trim segment of
the *measured* data, as seed 0 Table 1 is computed from flight data.

Outputs: an in-memory :class:`RunRecord` per run; ``write_run_bag`` writes it as a
rosbag2 directory with the topics of docs/DESIGN.md; ``write_trim_table`` writes
trims.yaml and trims.md.
"""

from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from lpv_sysid.control.baseline import BaselineController, BaselineGains
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.io.yaml_file import read_yaml
from lpv_sysid.models.quadrotor import Quadrotor, QuadrotorParams, Trim, mixer
from lpv_sysid.sim.vehicle import SensorConfig, SimVehicle
from lpv_sysid.config_fields import check_keys, is_count, is_finite_number

log = logging.getLogger(__name__)

REFERENCE_NAMES = ("u_d", "v_d", "w_d", "r_d")

# Seed 0 Table 1 (flight-data vertex equilibria), Table 1 row order, for comparison.
SEED0_TABLE1 = {
    (-5, -5, -5): (-4.99, -5.04, -4.20, -10.87, 9.28, 691.4, -36.7, 29.0, 310.5),
    (5, -5, -5): (4.95, -5.04, -4.17, -10.44, -8.05, 685.0, -34.1, -1.5, 39.2),
    (-5, 5, -5): (-5.01, 5.03, -3.95, 8.55, 8.11, 689.0, -2.8, 25.3, 34.9),
    (5, 5, -5): (5.03, 5.01, -4.00, 8.04, -8.98, 679.5, -5.8, -4.0, 305.4),
    (-5, -5, 5): (-4.83, -4.68, 2.88, -5.00, 3.17, 554.9, -45.0, 28.0, 367.6),
    (5, -5, 5): (4.73, -4.61, 2.72, -5.14, -4.08, 521.8, -34.6, -18.3, 158.9),
    (-5, 5, 5): (-4.85, 4.75, 3.00, 3.80, 3.00, 546.9, 14.0, 23.4, -9.8),
    (5, 5, 5): (4.64, 4.73, 2.86, 3.85, -4.83, 525.8, 3.49, -15.8, 298.1),
}
TRIM_COLUMNS = ("u0", "v0", "w0", "phi0_deg", "theta0_deg", "dt0", "da0", "de0", "dr0")


@dataclass(frozen=True)
class Phase1Config:
    """Phase-1 experiment settings (seed 0 Sec. IV)."""

    box_min: tuple = (-5.0, -5.0, -5.0)
    box_max: tuple = (5.0, 5.0, 5.0)
    trim_s: float = 10.0
    excite_s: float = 30.0
    trim_average_s: float = 5.0
    amplitudes: tuple = (1.5, 1.5, 1.0, 0.4)  # peak u, v, w [m/s], yaw rate [rad/s]
    f_min_hz: float = 0.2
    f_max_hz: float = 2.0
    taper_s: float = 1.0
    hover_validation: bool = True
    start: str = (
        "hover"  # "hover": reference steps from hover at t=0; "trim": start at the model trim
    )
    seed: int = 0

    def __post_init__(self) -> None:
        if self.start not in ("hover", "trim"):
            raise ConfigError(f"phase1.start: must be 'hover' or 'trim', got {self.start!r}")
        for name, n in (("box_min", 3), ("box_max", 3), ("amplitudes", 4)):
            v = getattr(self, name)
            try:
                arr = np.asarray(v, dtype=float)
            except (TypeError, ValueError):
                raise ConfigError(f"phase1.{name}: not numeric: {v!r}") from None
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise ConfigError(f"phase1.{name}: expected {n} finite numbers, got {v!r}")
            object.__setattr__(self, name, tuple(float(x) for x in arr))
        if any(a >= b for a, b in zip(self.box_min, self.box_max)):
            raise ConfigError("phase1.box_min: must be below box_max in every component")
        if any(a < 0 for a in self.amplitudes):
            raise ConfigError("phase1.amplitudes: must be >= 0")
        from lpv_sysid.signals.config import MAX_DURATION

        for name in ("trim_s", "excite_s", "trim_average_s", "f_min_hz", "f_max_hz", "taper_s"):
            v = getattr(self, name)
            if not is_finite_number(v) or v < 0:
                raise ConfigError(f"phase1.{name}: must be a finite number >= 0, got {v!r}")
            if name.endswith("_s") and v > MAX_DURATION:  # simulated before anything is written
                raise ConfigError(
                    f"phase1.{name}: {v:g} s exceeds the limit of {MAX_DURATION:g} s"
                )
            object.__setattr__(self, name, float(v))
        if self.trim_s <= 0 or self.excite_s <= 0:
            raise ConfigError("phase1.trim_s and phase1.excite_s: must be > 0")
        if not 0 < self.f_min_hz < self.f_max_hz:
            raise ConfigError("phase1.f_min_hz: need 0 < f_min_hz < f_max_hz")
        if not isinstance(self.hover_validation, bool):
            raise ConfigError("phase1.hover_validation: must be true or false")
        if not is_count(self.seed):
            raise ConfigError(f"phase1.seed: must be a non-negative integer, got {self.seed!r}")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Phase1Config":
        check_keys(d, {f.name for f in fields(cls)}, "phase1")
        return cls(**d)

    def scaled(self, s: float) -> "Phase1Config":
        """Durations multiplied by ``s`` (quick runs); the band is kept."""
        if not (math.isfinite(s) and s > 0):
            raise ConfigError(f"duration scale must be > 0, got {s}")
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        for name in ("trim_s", "excite_s", "trim_average_s", "taper_s"):
            kw[name] = kw[name] * s
        return Phase1Config(**kw)

    def vertices(self) -> list[tuple[float, float, float]]:
        """The 2^3 box corners in seed 0 Table 1 order (u fastest, then v, then w)."""
        return [
            (u, v, w)
            for w, v, u in itertools.product(
                (self.box_min[2], self.box_max[2]),
                (self.box_min[1], self.box_max[1]),
                (self.box_min[0], self.box_max[0]),
            )
        ]


@dataclass
class RunRecord:
    """Everything one simulated run produced (arrays in NED/FRD, SI units)."""

    name: str
    v_d: np.ndarray  # (3,) vertex body-velocity reference
    t_excite: float  # start of the excitation segment, s
    duration: float
    model_trim: Trim
    state_t: np.ndarray  # (N,)
    state_true: np.ndarray  # (N, 16) FULL_STATE_NAMES
    state_meas: np.ndarray  # (N, 16) estimator output (rotor columns = truth)
    rotor_t: np.ndarray  # (M,)
    rotor_meas: np.ndarray  # (M, 4) rad/s
    imu_t: np.ndarray  # (K,)
    imu_accel: np.ndarray  # (K, 3) specific force FRD
    imu_gyro: np.ndarray  # (K, 3) FRD
    cmd_t: np.ndarray  # (L,) control-rate time
    reference: np.ndarray  # (L, 4) u_d, v_d, w_d [m/s], r_d [rad/s]
    excitation: np.ndarray  # (L, 4) multisine part of the reference
    command: np.ndarray  # (L, 4) virtual command u = [ut, ua, ue, ur]
    meta: dict = field(default_factory=dict)

    def achieved_trim(self, average_s: float, arm_length: float) -> dict:
        """Mean over the last ``average_s`` of the trim segment (seed 0 Table 1 columns)."""
        t0 = max(0.0, self.t_excite - average_s)
        s = (self.state_t >= t0) & (self.state_t < self.t_excite)
        r = (self.rotor_t >= t0) & (self.rotor_t < self.t_excite)
        if not s.any() or not r.any():
            raise ConfigError(f"run {self.name}: no samples in the trim averaging window")
        xm = self.state_meas[s]
        delta = self.rotor_meas[r] @ mixer(arm_length).T
        vals = [
            *xm[:, 6:9].mean(axis=0),
            *np.degrees(xm[:, 3:5].mean(axis=0)),
            *delta.mean(axis=0),
        ]
        return {k: float(v) for k, v in zip(TRIM_COLUMNS, vals)}


def design_excitation(cfg: Phase1Config):
    """The phase-1 4-axis multisine (seed 0 Sec. IV): orthogonal, phase-optimised, flat
    spectrum in [f_min_hz, f_max_hz], one period of ``excite_s``, channels u, v, w, yaw-rate
    reference scaled to ``cfg.amplitudes`` (designed by :mod:`lpv_sysid.signals`)."""
    from lpv_sysid.signals.excitation import phase1_signals

    return phase1_signals(
        duration=cfg.excite_s,
        band=(cfg.f_min_hz, cfg.f_max_hz),
        peaks=cfg.amplitudes,
        sample_rate=50.0,
    )


def excitation_signal(cfg: Phase1Config, t: np.ndarray, signals=None) -> np.ndarray:
    """Excitation (N, 4) for excitation-segment times t in [0, excite_s], with cosine taper.

    ``signals`` is the designed :class:`~lpv_sysid.signals.multisine.SignalSet`
    (:func:`design_excitation`; designed here when None). It is evaluated as the exact sum
    of sinusoids at ``t``, so the control rate need not match the design grid.
    """
    if signals is None:
        signals = design_excitation(cfg)
    u = signals.evaluate(t)
    if cfg.taper_s > 0:
        w = np.ones_like(t)
        a = t < cfg.taper_s
        w[a] = 0.5 - 0.5 * np.cos(np.pi * t[a] / cfg.taper_s)
        b = t > cfg.excite_s - cfg.taper_s
        w[b] = 0.5 - 0.5 * np.cos(np.pi * (cfg.excite_s - t[b]) / cfg.taper_s)
        u = u * w[:, None]
    return u


def simulate_run(
    model: Quadrotor,
    gains: BaselineGains,
    sensors: SensorConfig,
    cfg: Phase1Config,
    v_d,
    name: str,
    seed: int,
    signals=None,
) -> RunRecord:
    """Fly one phase-1 run (trim then excitation) about body velocity ``v_d``.

    ``signals``: the designed excitation (:func:`design_excitation`), shared by all runs."""
    v_d = np.asarray(v_d, dtype=float)
    trim = model.trim(v_d)
    if gains.arm_length != model.params.arm_length:
        # the controller's output mixer must be the vehicle's (seed 0 Eq. 7)
        gains = replace(gains, arm_length=model.params.arm_length)
    phys = sensors.physics_hz
    d_ctrl = phys / gains.rate_hz
    if abs(d_ctrl - round(d_ctrl)) > 1e-9 or d_ctrl < 1:
        raise ConfigError(f"controller.rate_hz={gains.rate_hz} must divide sim.physics_hz={phys}")
    d_ctrl = int(round(d_ctrl))
    d_state, d_imu, d_rot = (
        sensors.decimation(r) for r in (sensors.state_hz, sensors.imu_hz, sensors.rotor_hz)
    )
    T = cfg.trim_s + cfg.excite_s
    n = int(round(T * phys))
    t_c = np.arange(0, n, d_ctrl) / phys
    exc = np.zeros((t_c.size, 4))
    on = t_c >= cfg.trim_s
    exc[on] = excitation_signal(cfg, t_c[on] - cfg.trim_s, signals)
    ref = exc + np.r_[v_d, 0.0]

    start = trim if cfg.start == "trim" else model.trim([0.0, 0.0, 0.0])
    veh = SimVehicle(model, SensorConfig(**{**sensors.to_dict(), "seed": seed}), start.full_state)
    veh.u = start.u0.tolist()
    ctrl = BaselineController(gains)
    ctrl.warm_start(start.x0, start.u0, start.v_d)

    ns, ni, nr = -(-n // d_state), -(-n // d_imu), -(-n // d_rot)
    state_t, state_true, state_meas = np.empty(ns), np.empty((ns, 16)), np.empty((ns, 16))
    imu_t, imu_a, imu_g = np.empty(ni), np.empty((ni, 3)), np.empty((ni, 3))
    rot_t, rot_m = np.empty(nr), np.empty((nr, 4))
    cmd = np.empty((t_c.size, 4))
    xm = np.empty(16)  # the measured state: set at k = 0 (d_state divides 0) before any use
    u = start.u0.tolist()
    for k in range(n):
        t = k / phys
        if k % d_state == 0:
            i = k // d_state
            state_t[i] = t
            state_true[i] = veh.x
            xm = veh.measure_state()
            state_meas[i] = xm
        if k % d_rot == 0:
            i = k // d_rot
            rot_t[i] = t
            rot_m[i] = veh.measure_rotors()
        if k % d_imu == 0:
            i = k // d_imu
            imu_t[i] = t
            imu_a[i], imu_g[i] = veh.measure_imu()
        if k % d_ctrl == 0:
            j = k // d_ctrl
            r = ref[j]
            x12 = (xm[3], xm[4], xm[6], xm[7], xm[8], xm[9], xm[10], xm[11])
            u = ctrl.step(t, x12, (r[0], r[1], r[2]), r[3]).tolist()
            cmd[j] = u
        try:
            veh.step(u)
        except SafetyError as exc_:
            raise SafetyError(f"run {name}: {exc_}; check gains/limits") from None
    return RunRecord(
        name=name,
        v_d=v_d,
        t_excite=cfg.trim_s,
        duration=T,
        model_trim=trim,
        state_t=state_t,
        state_true=state_true,
        state_meas=state_meas,
        rotor_t=rot_t,
        rotor_meas=rot_m,
        imu_t=imu_t,
        imu_accel=imu_a,
        imu_gyro=imu_g,
        cmd_t=t_c,
        reference=ref,
        excitation=exc,
        command=cmd,
        meta={"seed": seed, "physics_hz": phys, "control_hz": gains.rate_hz},
    )


def run_name(v_d) -> str:
    return "vertex_" + "_".join(
        f"{'p' if c > 0 else ('m' if c < 0 else '0')}{abs(c):g}" for c in v_d
    )


def run_phase1(
    model: Quadrotor,
    gains: BaselineGains,
    sensors: SensorConfig,
    cfg: Phase1Config,
    vertex_indices: Sequence[int] | None = None,
) -> list[RunRecord]:
    """All vertex runs (1-based Table 1 indices, default all) plus the hover validation."""
    verts = cfg.vertices()
    idx = list(range(1, len(verts) + 1)) if vertex_indices is None else list(vertex_indices)
    for i in idx:
        if not 1 <= i <= len(verts):
            raise ConfigError(f"vertex index {i} out of range 1..{len(verts)}")
    signals = design_excitation(cfg)
    runs = []
    for i in idx:
        log.info("phase 1: vertex %d %s", i, verts[i - 1])
        runs.append(
            simulate_run(
                model,
                gains,
                sensors,
                cfg,
                verts[i - 1],
                run_name(verts[i - 1]),
                seed=cfg.seed * 100 + i,
                signals=signals,
            )
        )
    if cfg.hover_validation:
        runs.append(
            simulate_run(
                model,
                gains,
                sensors,
                cfg,
                (0.0, 0.0, 0.0),
                "hover_validation",
                seed=cfg.seed * 100 + 99,
                signals=signals,
            )
        )
    return runs


def trim_table(runs: Sequence[RunRecord], cfg: Phase1Config, arm_length: float) -> list[dict]:
    rows = []
    for rec in runs:
        ach = rec.achieved_trim(cfg.trim_average_s, arm_length)
        x0 = rec.model_trim.x0
        model = dict(zip(TRIM_COLUMNS, [*x0[2:5], *np.degrees(x0[0:2]), *x0[8:12]]))
        row = {
            "run": rec.name,
            "vertex": [float(c) for c in rec.v_d],
            "achieved": ach,
            "model_trim": {k: float(v) for k, v in model.items()},
        }
        k0, k1, k2 = (int(round(c)) for c in rec.v_d)
        key = (k0, k1, k2)
        if key in SEED0_TABLE1:
            row["seed0_table1"] = dict(zip(TRIM_COLUMNS, SEED0_TABLE1[key]))
        rows.append(row)
    return rows


def write_trim_table(rows: Sequence[dict], out_dir: str | Path) -> tuple[Path, Path]:
    """trims.yaml (machine-readable) and trims.md (seed 0 Table 1 layout)."""
    out = Path(out_dir)
    y = out / "trims.yaml"
    y.write_text(
        yaml.safe_dump(
            {
                "format": "lpv_sysid/phase1_trims@1",
                "columns": list(TRIM_COLUMNS),
                "units": [
                    "m/s",
                    "m/s",
                    "m/s",
                    "deg",
                    "deg",
                    "rad/s",
                    "m*rad/s",
                    "m*rad/s",
                    "rad/s",
                ],
                "runs": list(rows),
            },
            sort_keys=False,
        )
    )
    m = out / "trims.md"
    m.write_text(format_trim_table(rows) + "\n")
    return y, m


def format_trim_table(rows: Sequence[dict]) -> str:
    head = "| vertex | source | " + " | ".join(TRIM_COLUMNS) + " |"
    lines = [head, "|" + "---|" * (len(TRIM_COLUMNS) + 2)]
    for row in rows:
        vtx = "[" + " ".join(f"{c:+g}" for c in row["vertex"]) + "]"
        for src in ("achieved", "model_trim", "seed0_table1"):
            if src in row:
                vals = " | ".join(
                    f"{row[src][k]:.2f}" if abs(row[src][k]) < 100 else f"{row[src][k]:.1f}"
                    for k in TRIM_COLUMNS
                )
                lines.append(f"| {vtx} | {src} | {vals} |")
    return "\n".join(lines)


def load_config(
    path: str | Path,
) -> tuple[QuadrotorParams, BaselineGains, SensorConfig, Phase1Config]:
    """Read config/quadrotor.yaml (sections quadrotor, controller, sim, phase1)."""
    p = Path(path)
    d = read_yaml(p)
    if not isinstance(d, dict):
        raise ConfigError(f"{p}: expected a mapping at top level")
    allowed = {"quadrotor", "controller", "sim", "phase1", "phase2"}
    bad = sorted(set(d) - allowed)
    if bad:
        raise ConfigError(f"{p}: unknown section(s) {bad}; allowed: {sorted(allowed)}")
    try:
        qp = QuadrotorParams.from_dict(d.get("quadrotor") or {})
        gains = BaselineGains.from_dict(d.get("controller") or {})
        sens = SensorConfig.from_dict(d.get("sim") or {})
        ph1 = Phase1Config.from_dict(d.get("phase1") or {})
    except TypeError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    except ConfigError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    return qp, gains, sens, ph1


TOPIC_NAMESPACE = "/lpv_sysid"
BAG_TOPICS = ("state", "rotor_speeds", "imu", "velocity_reference", "actuator_command", "status")


def write_run_bag(
    record: RunRecord, path: str | Path, storage: str = "mcap", namespace: str = TOPIC_NAMESPACE
) -> Path:
    """Write one run as a rosbag2 directory with the topics of docs/DESIGN.md.

    Topics (``namespace``/name): ``state`` (estimator output), ``rotor_speeds``, ``imu``
    (orientation from the nearest estimator sample), ``velocity_reference``,
    ``actuator_command`` and ``status`` (1 Hz, phase trim/excitation). Messages are those
    of the :mod:`lpv_sysid.io.messages` builders (frame conversions by
    :mod:`lpv_sysid.io.frames`), written by :class:`lpv_sysid.io.bag.BagWriter`; stamps are
    nanoseconds from the run start, messages in stamp order.

    The arrays are complete, so every topic is built in bulk: one builder message is the
    template, the frame conversions run on whole arrays and the CDR records come from
    :func:`lpv_sysid.io.bag.encode_block` (:func:`_bulk_rows`; first, middle and last record
    of each topic checked against the builder). A record the builders would reject (a
    non-finite value, a stamp beyond int32 seconds) sends the run through the builders
    message by message, which name the offending field.
    """
    from lpv_sysid.errors import BagError

    try:
        from lpv_sysid.io import messages as M
        from lpv_sysid.io.bag import BagWriter
    except ImportError as exc:
        raise BagError(f"{path}: rosbag2 writing unavailable ({exc})") from None
    f = M.MsgFactory.rosbags()
    path = Path(path)
    topic = {name: f"{namespace}/{name}" for name in BAG_TOPICS}
    rows = _bulk_rows(record, f, topic)
    try:
        with BagWriter(str(path), storage=storage) as w:
            for name in BAG_TOPICS:
                w.add_topic(topic[name], M.TYPES[name])
            if rows is not None:
                w.write_many(rows)
            else:
                for stamp, name, msg in _message_items(record, f):
                    w.write(topic[name], stamp, msg)
    except BagError:
        raise
    except OSError as exc:
        raise BagError(f"{path}: cannot write bag ({exc})") from None
    return path


def _stamp_ns(t) -> int:
    return int(round(float(t) * 1e9))


def _status_items(record: RunRecord, f) -> list:
    from lpv_sysid.io import messages as M

    items = []
    for t in np.arange(0.0, record.duration, 1.0):
        phase = "trim" if t < record.t_excite else "excitation"
        st = M.diagnostic_status(
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
        items.append((_stamp_ns(t), "status", M.diagnostic_array(f, _stamp_ns(t), [st])))
    return items


def _imu_state_index(record: RunRecord) -> np.ndarray:
    """Index of the estimator sample whose attitude each IMU message carries."""
    return np.clip(
        np.searchsorted(record.state_t, record.imu_t, side="right") - 1, 0, len(record.state_t) - 1
    )


def _message_items(record: RunRecord, f) -> list:
    """(stamp_ns, topic name, message) of every message, built one at a time, stamp order."""
    from lpv_sysid.io import messages as M

    ns = _stamp_ns
    items: list[tuple[int, str, Any]] = []
    xm = record.state_meas
    for t, x in zip(record.state_t, xm):
        items.append(
            (ns(t), "state", M.odometry_from_state(f, ns(t), x[0:3], x[3:6], x[6:9], x[9:12]))
        )
    for t, om in zip(record.rotor_t, record.rotor_meas):
        items.append((ns(t), "rotor_speeds", M.rotor_speeds_msg(f, ns(t), om)))
    for t, a, w, i in zip(
        record.imu_t, record.imu_accel, record.imu_gyro, _imu_state_index(record)
    ):
        items.append((ns(t), "imu", M.imu_msg(f, ns(t), a, w, xm[i, 3:6])))
    for t, r, u in zip(record.cmd_t, record.reference, record.command):
        items.append(
            (ns(t), "velocity_reference", M.twist_reference_msg(f, ns(t), r[0:3], float(r[3])))
        )
        items.append((ns(t), "actuator_command", M.actuator_command_msg(f, ns(t), u)))
    items.extend(_status_items(record, f))
    items.sort(key=lambda it: it[0])
    return items


def _bulk_rows(record: RunRecord, f, topic: Mapping[str, str]):
    """``(topic, stamp_ns, CDR record)`` of every message of :func:`write_run_bag` in the order
    of :func:`_message_items`, built per topic with :func:`lpv_sysid.io.bag.encode_block`;
    None when a sample would be rejected by the builders or a record disagrees with them."""
    from lpv_sysid.io import frames
    from lpv_sysid.io import messages as M
    from lpv_sysid.io.bag import LayoutError, encode_block, jazzy_typestore, records_close

    def stamps(t):
        t = np.asarray(t, dtype=float)
        if t.size == 0 or not np.all(np.isfinite(t)):
            return None
        ns = np.round(t * 1e9).astype(np.int64)
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
                M.odometry_from_state,
                lambda k: (xm[k, 0:3], xm[k, 3:6], xm[k, 6:9], xm[k, 9:12]),
                {
                    **xyz("pose.pose.position", pos),
                    **quat("pose.pose.orientation", q),
                    **xyz("twist.twist.linear", v),
                    **xyz("twist.twist.angular", w),
                },
            ),
            "rotor_speeds": (
                M.rotor_speeds_msg,
                lambda k: (record.rotor_meas[k],),
                {"velocity": np.asarray(record.rotor_meas, dtype=float)},
            ),
            "imu": (
                M.imu_msg,
                lambda k: (record.imu_accel[k], record.imu_gyro[k], xm[ii[k], 3:6]),
                {
                    **quat("orientation", q[ii]),
                    **xyz("angular_velocity", gyr),
                    **xyz("linear_acceleration", acc),
                },
            ),
            "velocity_reference": (
                M.twist_reference_msg,
                lambda k: (ref[k, 0:3], float(ref[k, 3])),
                {**xyz("twist.linear", vref), **xyz("twist.angular", wref)},
            ),
            "actuator_command": (
                M.actuator_command_msg,
                lambda k: (record.command[k],),
                {"position": np.asarray(record.command, dtype=float)},
            ),
        }
        ts = jazzy_typestore()
        data = {}
        for name, (build, args, values) in templates.items():
            ns, head = blocks[name]
            msgtype = M.TYPES[name]
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
    except (LayoutError, M.MessageError, ValueError) as exc:
        log.warning(
            "run %s: bulk bag writing unavailable (%s); writing message by message",
            record.name,
            exc,
        )
        return None
    status = [
        (ns, "status", bytes(ts.serialize_cdr(msg, M.TYPES["status"])))
        for ns, _, msg in _status_items(record, f)
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
