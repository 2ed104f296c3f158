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
:mod:`~lpv_sysid.sim.closed_loop.excitation_fir`); outputs (:mod:`~lpv_sysid.sim.phase2.outputs`).
The run itself: :mod:`~lpv_sysid.sim.phase2.experiment` (:func:`run`).
"""

from __future__ import annotations

from lpv_sysid.sim.phase2.bag import BAG_TOPICS, SAMPLE_TOPICS, Phase2Bag
from lpv_sysid.sim.phase2.experiment import run
from lpv_sysid.sim.phase2.flight import excitation_gain_by_superposition, simulate_nonlinear
from lpv_sysid.sim.phase2.gain import decompose_eq33, gain_decomposition, offset_output
from lpv_sysid.sim.phase2.inputs import (
    EXCITATION_CHANNELS,
    REFERENCE_CHANNELS,
    Phase2Config,
    Phase2Problem,
    load_problem,
    load_signals,
    load_vehicle_config,
    reference_signals,
)
from lpv_sysid.sim.phase2.law import RuntimeLaw
from lpv_sysid.sim.phase2.outputs import RunRecord, regressor_correlation_block, write_outputs

__all__ = [
    "BAG_TOPICS",
    "EXCITATION_CHANNELS",
    "Phase2Bag",
    "Phase2Config",
    "Phase2Problem",
    "REFERENCE_CHANNELS",
    "RunRecord",
    "RuntimeLaw",
    "SAMPLE_TOPICS",
    "decompose_eq33",
    "excitation_gain_by_superposition",
    "gain_decomposition",
    "load_problem",
    "load_signals",
    "load_vehicle_config",
    "offset_output",
    "reference_signals",
    "regressor_correlation_block",
    "run",
    "simulate_nonlinear",
    "write_outputs",
]
