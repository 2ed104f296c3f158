"""Phase-2 experiment simulation (seed 0 Sec. VII): the LPV-controlled excitation flight.

Two simulations of the same 7-channel signal (reference ``u_d, v_d, w_d`` and normalised
excitation ``ue_t, ue_a, ue_e, ue_r``, excitation multiplier ``kappa``):

(a) the LPV closed loop of Eq. (33) at nominal parameters (:mod:`lpv_sysid.sim.closed_loop`,
    scheduled model from ``vertex_models.yaml`` + ``gains.yaml`` via :mod:`lpv_sysid.models.lpv`);
    with reference feedforward in the gains (F_ff) also ``linear_ff``: the same linear model
    without Eq. (33)'s ``x0'`` term under the feedforward law (the linear counterpart of (b));
(b) the full nonlinear quadrotor of :mod:`lpv_sysid.models.quadrotor` under the runtime LPV law
    (:mod:`lpv_sysid.control.law.controller`) fed with the simulated *measured* state (sensor
    model of :mod:`lpv_sysid.sim.vehicle`), recorded to a rosbag2 with the DESIGN.md topics
    (:mod:`lpv_sysid.sim.phase2.flight`, :mod:`lpv_sysid.sim.phase2.bag`).

Both report the achieved u_e -> z gain (z = Q^-1 (v - v_d), Eq. 18) against the design gamma
(Eq. 29, see below), tracking (Figs. 8-9) and the correlation of the Eq. (6) regressors
(Fig. 10). The safety supervisor of :mod:`lpv_sysid.control.safety` stops run (b) --
excitation off, event reported -- when the vehicle leaves the scheduling box (plus a margin),
tilts beyond a limit, or its state becomes non-finite; the runtime law's bound monitor flag
stops it too.

On the nonlinear vehicle z also holds the lag in following v_d (absent from Eq. 33, where x0'
moves the equilibrium); the reference feedforward of gains.yaml (``Phase2Config.feedforward``
``exact``: a and its rate from the signal table; ``filtered``: the onboard derivative filter)
removes most of it; :func:`excitation_gain_by_superposition` (``superposition``) separates the
excitation response by flying with and without u_e under identical sensor noise.

What gamma bounds, and what the summary reports.  ``z = Q^-1 (v - v_d)`` holds three parts:
the response to the excitation ``u_e`` (the only part Lemma 1 bounds, Eq. 29), the lag in
following ``v_d`` (in Eq. 33 the response to the ``x0'`` forcing, on the vehicle the
acceleration it must produce) and the equilibrium offset ``Q^-1 (v0(v_d) - v_d)`` (the vertex
equilibria fly a velocity that differs from the commanded one, seed 0 Table 1).  Every run's
ratio is split (:func:`gain_decomposition`): ``excitation_gain`` = ``||z_e||_2 / ||kappa u_e||_2``
with ``z_e`` from superposition (Eq. 33 and ``linear_ff``: exact, a second run with ``-u_e``;
nonlinear with ``superposition``: two more flights) or, on the nonlinear run otherwise, from
a FIR regression of ``z`` on ``u_e`` above the reference band
(:func:`lpv_sysid.sim.closed_loop.excitation_fir.excitation_response_fir`);
the offset part exactly from the schedule; tracking = the rest.  ``within_gamma`` refers to
``excitation_gain``; ``total_ratio`` = ``||z||_2 / ||kappa u_e||_2`` mixes all three.

Outputs in the output directory (:mod:`lpv_sysid.sim.phase2.outputs`, read by
:mod:`lpv_sysid.report`): ``summary.yaml``, ``eq33.npz`` / ``nonlinear.npz`` (time
histories), PNG figures, and ``bag/`` (rosbag2).

Modules: options, gains, signals (:mod:`~lpv_sysid.sim.phase2.inputs`); the runtime law
(:mod:`~lpv_sysid.sim.phase2.law`); the nonlinear flight (:mod:`~lpv_sysid.sim.phase2.flight`);
its bag (:mod:`~lpv_sysid.sim.phase2.bag`); what gamma bounds (:mod:`~lpv_sysid.sim.phase2.gain`,
:mod:`~lpv_sysid.sim.closed_loop.excitation_fir`); outputs (:mod:`~lpv_sysid.sim.phase2.outputs`). This
module runs them (:func:`run`) and re-exports their public names.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from lpv_sysid.errors import BagError, ConfigError, SafetyError
from lpv_sysid.sim.closed_loop import (
    ClosedLoopConfig,
    ControlLaw,
    ReferenceSignals,
    excitation_response_fir,
    simulate_eq33,
)
from lpv_sysid.sim.phase2.bag import Phase2Bag
from lpv_sysid.sim.phase2.flight import excitation_gain_by_superposition, simulate_nonlinear
from lpv_sysid.sim.phase2.gain import decompose_eq33, gain_decomposition, offset_output
from lpv_sysid.sim.phase2.inputs import Phase2Config, Phase2Problem, reference_acceleration
from lpv_sysid.sim.phase2.law import RuntimeLaw, runtime_law
from lpv_sysid.sim.phase2.outputs import (
    RunRecord,
    record_from_eq33,
    regressor_correlation_block,
    write_outputs,
)

log = logging.getLogger(__name__)


@dataclass
class Phase2Result:
    records: dict[str, RunRecord]
    skipped: dict[str, str]
    written: dict[str, Path]
    summary_path: Path
    #: the Fig. 10 regressor correlation of ``summary.yaml`` (None without a run to show)
    regressor_block: Optional[dict] = None


def run(
    problem: Phase2Problem,
    signals: ReferenceSignals,
    cfg: Phase2Config,
    quad_params: Any,
    sensors: Any,
    out_dir: str | Path,
    law: Optional[ControlLaw] = None,
) -> Phase2Result:
    """Runs (a) and (b), writes the outputs (see module docstring) and returns them."""
    out = _output_dir(out_dir)
    if cfg.run_nonlinear and cfg.record_bag and (out / "bag").exists():
        raise ConfigError(f"output directory: {out / 'bag'} exists; choose an empty one")
    if np.any((signals.v_d < problem.vmin - 1e-9) | (signals.v_d > problem.vmax + 1e-9)):
        raise ConfigError(
            "signals: the reference v_d leaves the scheduling box of the gains "
            f"[{problem.vmin.tolist()}, {problem.vmax.tolist()}]"
        )
    records: dict[str, RunRecord] = {}
    skipped: dict[str, str] = {}
    if cfg.run_eq33:
        _run_linear(problem, signals, cfg, records, skipped)
    else:
        skipped["eq33"] = "not requested"
    bag_path = out / "bag" if cfg.run_nonlinear and cfg.record_bag else None
    if cfg.run_nonlinear:
        log.info("phase 2: nonlinear flight (%.1f s)", float(signals.t[-1] - signals.t[0]))
        try:
            rec = _fly(problem, signals, cfg, quad_params, sensors, bag_path, law)
        except BagError as exc:
            # the bag is closed (readable up to the failure); keep the other results, then fail
            skipped["nonlinear"] = f"recording failed: {exc}"
            write_outputs(out, problem.gamma, cfg.kappa, list(records.values()), skipped)
            raise
        records["nonlinear"] = rec
    else:
        skipped["nonlinear"] = "not requested"
    block = _regressor_block(records, quad_params.arm_length)
    written = write_outputs(
        out,
        problem.gamma,
        cfg.kappa,
        list(records.values()),
        skipped,
        block,
        _summary_extra(problem, signals, cfg, quad_params.arm_length),
    )
    if bag_path is not None:
        written["bag"] = bag_path
    return Phase2Result(records, skipped, written, written["summary"], block)


def _output_dir(out_dir: str | Path) -> Path:
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"output directory: cannot create {out} ({exc.strerror})") from None
    return out


def _run_linear(
    problem: Phase2Problem,
    signals: ReferenceSignals,
    cfg: Phase2Config,
    records: dict[str, RunRecord],
    skipped: dict[str, str],
) -> None:
    """Run (a): Eq. (33) and, with feedforward in the gains, ``linear_ff`` (into ``records``,
    or the reason into ``skipped``)."""
    if problem.A is None:
        skipped["eq33"] = "no vertex models (vertex_models.yaml) to simulate Eq. (33)"
        return
    sched = problem.scheduled()
    cl = ClosedLoopConfig(kappa=cfg.kappa, method=cfg.eq33_method)
    log.info("phase 2: Eq. (33) closed loop (%s)", cfg.eq33_method)
    try:
        res = simulate_eq33(sched, signals, problem.R, problem.Q, problem.gamma, cl)
        records["eq33"] = record_from_eq33(res)
        records["eq33"].decomposition = decompose_eq33(problem, signals, res, cfg)
    except SafetyError as exc:
        skipped["eq33"] = f"diverged: {exc}"
    if problem.F_ff is None or cfg.feedforward == "off":
        return
    # linear model without the x0' term + the feedforward law (lpv_closed_loop docstring)
    from lpv_sysid.sim.closed_loop import FeedforwardSchedule, feedforward_law

    names = list(problem.state_names)
    spec = problem.feedforward
    ffs = FeedforwardSchedule(
        problem.vmin,
        problem.vmax,
        problem.F_ff,
        [names.index(s_) for s_ in spec.free_states],
        len(names),
        problem.F_jerk,
        [names.index(s_) for s_ in spec.rate_states],
    )

    def ff_law() -> ControlLaw:
        return feedforward_law(sched, problem.R, ffs, reference_acceleration(signals))

    log.info("phase 2: linear model with the feedforward law (linear_ff)")
    try:
        res = simulate_eq33(
            sched,
            signals,
            problem.R,
            problem.Q,
            problem.gamma,
            cl,
            law=ff_law(),
            moving_equilibrium=False,
        )
        records["linear_ff"] = record_from_eq33(res, "linear_ff")
        records["linear_ff"].decomposition = decompose_eq33(
            problem, signals, res, cfg, ff_law(), moving_equilibrium=False
        )
    except SafetyError as exc:
        skipped["linear_ff"] = f"diverged: {exc}"


def _fly(
    problem: Phase2Problem,
    signals: ReferenceSignals,
    cfg: Phase2Config,
    quad_params: Any,
    sensors: Any,
    bag_path: Optional[Path],
    law: Optional[ControlLaw],
) -> RunRecord:
    """Run (b): the nonlinear flight (recorded to ``bag_path`` unless None) with its gain
    decomposition (superposition flights or the FIR regression)."""
    from lpv_sysid.models.quadrotor import Quadrotor
    from lpv_sysid.sim.vehicle import SimVehicle

    quad = Quadrotor(quad_params)
    trim = quad.trim(signals.v_d[0])

    def the_law(monitor_margin: float, monitor_window: Optional[float]) -> RuntimeLaw:
        return runtime_law(
            problem,
            quad.mix,
            monitor_margin,
            cfg.feedforward,
            signals,
            monitor_window,
            cfg.ff_filter_tau,
            cfg.ff_jerk_tau,
        )

    def fly(sink: Optional[Phase2Bag]) -> RunRecord:
        return simulate_nonlinear(
            SimVehicle(quad, sensors, x0=trim.full_state),
            law or the_law(cfg.monitor_margin, cfg.monitor_window),
            signals,
            problem.Q,
            problem.vmin,
            problem.vmax,
            kappa=cfg.kappa,
            gamma=problem.gamma,
            box_margin=cfg.box_margin,
            max_tilt=math.radians(cfg.max_tilt_deg),
            sink=sink,
        )

    if bag_path is None:
        rec = fly(None)
    else:
        with Phase2Bag(bag_path, cfg.storage, kappa=cfg.kappa) as bag:
            rec = fly(bag)
        rec.info["bag"] = str(bag_path)
        rec.info["bag_messages"] = dict(bag.counts)
    z_off = offset_output(problem, rec.v_d)
    if cfg.superposition:
        log.info("phase 2: superposition flights (with and without u_e)")
        # the bound monitor does not stop these flights (it would stop on the
        # reference-tracking part of z): excitation_gain_by_superposition
        sp = excitation_gain_by_superposition(
            lambda: SimVehicle(quad, sensors, x0=trim.full_state),
            lambda: the_law(cfg.monitor_margin, None),
            signals,
            problem.Q,
            problem.vmin,
            problem.vmax,
            kappa=cfg.kappa,
            box_margin=cfg.box_margin,
            max_tilt=math.radians(cfg.max_tilt_deg),
            arrays=True,
        )
        t_sp, z_e = sp.pop("t"), sp.pop("z_e")
        sp.pop("z_reference")
        rec.info["superposition"] = sp
        n = min(t_sp.size, rec.t.size)
        rec.decomposition = gain_decomposition(
            rec.t[:n],
            rec.z[:n],
            rec.ue[:n],
            z_off[:n],
            z_e[:n],
            "superposition (two more flights, with and without u_e, same sensor noise)",
        )
    elif rec.t.size >= 10:
        try:
            z_e, info = excitation_response_fir(rec.t, rec.z - z_off, rec.ue)
            rec.decomposition = gain_decomposition(
                rec.t,
                rec.z,
                rec.ue,
                z_off,
                z_e,
                "FIR regression of z on u_e above the reference band",
                **info,
            )
        except ConfigError as exc:
            rec.decomposition = gain_decomposition(
                rec.t, rec.z, rec.ue, z_off, None, f"not separated: {exc}"
            )
    return rec


def _regressor_block(records: dict[str, RunRecord], arm_length: float) -> Optional[dict]:
    """Fig. 10 data: the nonlinear flight when it completed; else the Eq. (33) run (what the
    seed used); else whatever part of the nonlinear flight there is."""
    nl, eq = records.get("nonlinear"), records.get("eq33")
    order = [nl, eq] if nl is not None and nl.completed else [eq, nl]
    for rec in order:
        if rec is not None and rec.t.size >= 10:
            block = regressor_correlation_block(
                rec.t, rec.controller_state, arm_length, rec.name, rec.extra.get("Omega")
            )
            block["complete_run"] = bool(rec.completed)
            return block
    return None


def _summary_extra(
    problem: Phase2Problem, signals: ReferenceSignals, cfg: Phase2Config, arm_length: float
) -> dict:
    from lpv_sysid.control.law import LpvControllerConfig

    return {
        "box": {"min": problem.vmin.tolist(), "max": problem.vmax.tolist()},
        # the limits this run was supervised against (the report's margins use them)
        "limits": {
            "max_tilt_deg": float(cfg.max_tilt_deg),
            "box_margin": float(cfg.box_margin),
            "monitor_margin": float(cfg.monitor_margin),
            "monitor_min_energy": float(LpvControllerConfig.monitor_min_energy),
            "arm_length": float(arm_length),
        },
        "inputs": {k: str(v) for k, v in problem.source.items()},
        "signals": {
            "duration": float(signals.t[-1] - signals.t[0]),
            "samples": int(signals.t.size),
            "ramp": cfg.ramp,
        },
    }
