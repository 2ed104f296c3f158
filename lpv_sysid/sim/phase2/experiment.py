"""One phase-2 simulation (:func:`run`): run (a), Eq. (33) and ``linear_ff``, and run (b),
the nonlinear flight, with their outputs; the method is the :mod:`lpv_sysid.sim.phase2`
docstring."""

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
