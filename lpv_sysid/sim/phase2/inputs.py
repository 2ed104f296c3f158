"""Inputs of a phase-2 run (seed 0 Sec. VII): options, gains and models, signals, vehicle.

:class:`Phase2Config` holds the options (the CLI ``simulate phase2`` maps its flags onto the
fields; errors here name the field), :class:`Phase2Problem` what is flown (``gains.yaml`` and
optionally ``vertex_models.yaml``, read through :mod:`lpv_sysid.io.formats`),
:func:`load_signals` the 7-channel ``signals.npz`` (reference ``u_d, v_d, w_d``, normalised
excitation ``ue_t, ue_a, ue_e, ue_r``) and :func:`load_vehicle_config` the simulated vehicle.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.control.law import check_kappa
from lpv_sysid.errors import ConfigError
from lpv_sysid.sim.closed_loop import ReferenceSignals

log = logging.getLogger(__name__)

REFERENCE_CHANNELS = ("u_d", "v_d", "w_d")
EXCITATION_CHANNELS = ("ue_t", "ue_a", "ue_e", "ue_r")


# --------------------------------------------------------------------------- options
@dataclass(frozen=True)
class Phase2Config:
    """Options of the phase-2 simulation (``simulate phase2`` maps its flags onto the fields;
    errors name the field)."""

    kappa: float = cf.number(
        1.0, "excitation multiplier of Eq. (33) (range: control.law.check_kappa)"
    )
    eq33_method: str = cf.choice(
        "rk4", ("RK45", "rk4"), "rk4: fixed step on the signal grid; RK45: ode45-like"
    )
    box_margin: float = cf.number(
        1.0,
        "beyond the scheduling box before the supervisor stops (a wider margin leaves the "
        "certified box unguarded)",
        lo=0.0,
        hi=1.0,
        unit=" m/s",
    )
    max_tilt_deg: float = cf.number(
        60.0,
        "|phi|, |theta| limit of the supervisor",
        lo=0.0,
        lo_open=True,
        hi=90.0,
        hi_open=True,
        unit=" deg",
    )
    duration: Optional[float] = cf.number(
        None,
        "truncate the signals to this many seconds",
        lo=0.0,
        lo_open=True,
        unit=" s",
        optional=True,
    )
    ramp: Optional[float] = cf.number(
        2.0,
        "fade in/out of the excitation player (null: raw table)",
        lo=0.0,
        hi=600.0,
        unit=" s",
        optional=True,
    )
    record_bag: bool = cf.flag(True, "write the phase-2 bag of run (b)")
    storage: str = cf.choice("mcap", ("mcap", "sqlite3"), "rosbag2 storage of that bag")
    seed: int = cf.count(0, "sensor-noise seed of run (b)")
    run_eq33: bool = cf.flag(True, "run (a): Eq. (33) on the identified models")
    run_nonlinear: bool = cf.flag(True, "run (b): the nonlinear simulated vehicle")
    monitor_margin: float = cf.number(
        1.2, "bound monitor of the runtime law: flag at gain > gamma x margin", lo=1.0, hi=10.0
    )
    superposition: bool = cf.flag(
        False, "also estimate the excitation-only gain on the nonlinear model"
    )
    feedforward: str = cf.choice(
        "exact", ("exact", "filtered", "off"), "reference feedforward of run (b)"
    )
    ff_filter_tau: float = cf.number(
        0.05, "derivative filter of the 'filtered' feedforward", lo=0.0, hi=10.0, unit=" s"
    )
    ff_jerk_tau: float = cf.number(0.2, "its jerk stage", lo=0.0, hi=10.0, unit=" s")
    monitor_window: Optional[float] = cf.number(
        None,
        "exponential forgetting of the bound monitor",
        lo=0.0,
        lo_open=True,
        unit=" s",
        optional=True,
    )

    def __post_init__(self) -> None:
        cf.normalize_fields(self, "phase2")
        check_kappa(self.kappa, "kappa", positive=True)  # the controller's range (Eq. 33)


# --------------------------------------------------------------------------- gains and models
@dataclass
class Phase2Problem:
    """What phase 2 flies: vertex gains/equilibria (gains.yaml), weights R, Q, the design gamma,
    and optionally the nominal vertex models (vertex_models.yaml) for Eq. (33)."""

    vmin: np.ndarray
    vmax: np.ndarray
    K: np.ndarray  # (N, n_u, n_x), Eq. (31)
    x0: np.ndarray  # (N, n_x)
    u0: np.ndarray  # (N, n_u)
    R: np.ndarray  # (n_u, n_e), Eq. (27)
    Q: np.ndarray  # (3, 3), Eq. (28)
    gamma: Optional[float]
    A: Optional[np.ndarray] = None  # (N, n_x, n_x) nominal vertex models (theta0)
    B: Optional[np.ndarray] = None  # (N, n_x, n_u)
    source: dict = field(default_factory=dict)
    F_ff: Optional[np.ndarray] = None  # (N, n_free + n_u, 3) reference feedforward (gains.yaml)
    F_jerk: Optional[np.ndarray] = None  # (N, n_free + n_u + n_rate, 3) its jerk term
    feedforward: Any = None  # its layout (io.formats.FeedforwardSpec), None: no feedforward
    state_names: tuple = ()
    design: Any = None  # certificate.design (io.formats.DesignEnvelope), None: not recorded

    def scheduled(self):
        """ScheduledLpv of the nominal model with the gains' equilibria (Eq. 33 inputs)."""
        from lpv_sysid.models.lpv import PolytopicModel, ScheduledLpv

        if self.A is None or self.B is None:
            raise ConfigError("Eq. (33) needs the vertex models (vertex_models.yaml)")
        pm = PolytopicModel(
            vmin=self.vmin, vmax=self.vmax, A=self.A, B=self.B, x0=self.x0, u0=self.u0
        )
        return ScheduledLpv(pm, self.K)


def load_problem(
    gains_path: str | Path, models_path: Optional[str | Path] = None
) -> Phase2Problem:
    """Phase2Problem from ``gains.yaml`` (+ ``vertex_models.yaml``), validated by
    :mod:`lpv_sysid.io.formats`: with a models file the gains must match it (names, box,
    vertex equilibria and the certificate's SHA-256 of the models file)."""
    from lpv_sysid.io.formats import GainSchedule, VertexModels

    gains_path = Path(gains_path)
    if not os.path.lexists(gains_path):
        raise ConfigError(f"gains file {gains_path} not found")
    if models_path is not None and not os.path.lexists(models_path):
        raise ConfigError(f"models file {models_path} not found")
    gs = GainSchedule.load(gains_path, models_path)
    source = {"gains": gains_path}
    A = B = None
    if models_path is not None:
        vm = VertexModels.load(models_path)
        source["models"] = Path(models_path)
        if vm.ts is None:
            A, B = vm.A, vm.B
        else:
            log.warning(
                "%s: discrete-time models (Ts=%g); Eq. (33) is continuous, skipped",
                models_path,
                vm.ts,
            )
    return Phase2Problem(
        vmin=np.asarray(gs.scheduling.min, dtype=float),
        vmax=np.asarray(gs.scheduling.max, dtype=float),
        K=gs.K,
        x0=gs.x0,
        u0=gs.u0,
        R=np.asarray(gs.R, dtype=float),
        Q=np.asarray(gs.Q, dtype=float),
        gamma=float(gs.gamma),
        A=A,
        B=B,
        source=source,
        F_ff=gs.F_ff,
        F_jerk=gs.F_jerk,
        feedforward=gs.feedforward,
        state_names=tuple(gs.state_names),
        design=gs.certificate.design,
    )


# --------------------------------------------------------------------------- signals
def reference_signals(
    t: np.ndarray, u: np.ndarray, names: Sequence[str], duration: Optional[float] = None
) -> ReferenceSignals:
    """Pick the reference and excitation channels of ``signals.npz`` by name."""
    names = [str(n) for n in names]
    u = np.asarray(u, dtype=float)
    t = np.asarray(t, dtype=float)
    if u.ndim != 2 or u.shape[1] != len(names):
        raise ConfigError(
            f"signals.npz: 'u' has shape {u.shape}, 'names' has {len(names)} entries"
        )
    missing = [c for c in REFERENCE_CHANNELS + EXCITATION_CHANNELS if c not in names]
    if missing:
        raise ConfigError(f"signals.npz: channel(s) {missing} missing; have {names}")
    if duration is not None:
        keep = t <= t[0] + duration + 1e-12
        t, u = t[keep], u[keep]
    vd = u[:, [names.index(c) for c in REFERENCE_CHANNELS]]
    ue = u[:, [names.index(c) for c in EXCITATION_CHANNELS]]
    return ReferenceSignals(t, vd, ue)


def load_signals(
    signals_dir: str | Path,
    duration: Optional[float] = None,
    ramp: Optional[float] = None,
    design: Any = None,
) -> ReferenceSignals:
    """``DIR/signals.npz`` (t, u, names) -> ReferenceSignals; ConfigError naming the problem.

    With ``ramp`` (seconds) the table is played as the excitation node plays it
    (:meth:`lpv_sysid.signals.excitation.ExcitationCore.phase2`: raised-cosine fade in and out
    of that length around one period, so v_d starts and ends at zero, i.e. hover), sampled on
    the table's own time step; without it the raw table is used.
    """
    from lpv_sysid.signals.store import load_npz

    path = Path(signals_dir)
    if path.is_dir():
        path = path / "signals.npz"
    if not os.path.lexists(path):
        raise ConfigError(f"signals: {path} not found")
    t, u, table_names = load_npz(str(path))  # safe open + table checks (store.validate_table)
    if design is not None:
        # the check the flight path makes (excitation node with gains_file): a table beyond
        # the gains' design envelope (e.g. x 20) is refused, not simulated
        from lpv_sysid.signals.excitation import check_design

        check_design(t, u, table_names, design, float(ramp or 0.0), where=str(path))
    names = [str(n) for n in table_names]
    sig = reference_signals(t, u, names)  # validates channels by name
    if ramp is None:
        return reference_signals(t, u, names, duration)
    from lpv_sysid.signals.excitation import ExcitationCore

    core = ExcitationCore.phase2(t, u, names, start_time=0.0, ramp=float(ramp))
    dt = float(np.median(np.diff(sig.t)))
    end = core.duration if duration is None else min(core.duration, float(duration))
    grid = np.arange(0.0, end + 0.5 * dt, dt)
    vel, _, ue = core.evaluate(grid)
    return ReferenceSignals(grid, vel, ue)


def reference_acceleration(
    signals: ReferenceSignals,
) -> Callable[[float], tuple[np.ndarray, np.ndarray]]:
    """(a, j)(t) = (dv_d/dt, d2v_d/dt2) of the reference table for the feedforward: second-order
    central differences of the samples (np.gradient, applied twice; one-sided at the ends),
    linearly interpolated. For the phase-2 multisine (<= 0.5 Hz sampled at 50 Hz) the relative
    error is (2 pi f dt)^2 / 6 < 7e-4 per derivative."""
    t = signals.t
    acc = np.gradient(signals.v_d, t, axis=0, edge_order=2)
    jerk = np.gradient(acc, t, axis=0, edge_order=2)
    both = np.hstack([acc, jerk])
    p = acc.shape[1]

    def aj(tk: float) -> tuple[np.ndarray, np.ndarray]:
        k = min(max(int(np.searchsorted(t, tk, side="right")) - 1, 0), t.size - 2)
        s = min(max((tk - t[k]) / (t[k + 1] - t[k]), 0.0), 1.0)
        v = (1.0 - s) * both[k] + s * both[k + 1]
        return v[:p], v[p:]

    return aj


# --------------------------------------------------------------------------- vehicle
def load_vehicle_config(path: Optional[str | Path], seed: Optional[int] = None):
    """(QuadrotorParams, SensorConfig) from ``config/quadrotor.yaml`` (sections quadrotor, sim)."""
    from dataclasses import replace

    from lpv_sysid.models.quadrotor import QuadrotorParams
    from lpv_sysid.sim.vehicle import SensorConfig

    if path is None:
        qp, sens = QuadrotorParams(), SensorConfig()
    else:
        from lpv_sysid.sim.phase1 import load_config

        qp, _, sens, _ = load_config(path)
    if seed is not None:
        sens = replace(sens, seed=int(seed))
    return qp, sens
