"""Start-up of the flight controller: what happens once, before any command can exist.

:func:`load_flight_schedule`: the gains file is validated (io/formats), the law it holds must
hash to ``certificate.gains_sha256`` (the K that flies is the K that was certified), the whole
file must match its seal (with ``seal_key_file``: the operator's keyed seal), every
``A_ij + B_ij K_i`` of the certified systems in the sidecar must be Hurwitz (eigenvalues only,
milliseconds), the certificate must carry the design envelope of the phase-2 signal, and the
ESC limits must contain every vertex trim (virtual-actuator design); any failure refuses to start,
naming the reason. The design flown is read from the gains file (:func:`design_of`): the
virtual-actuator quadrotor of seed 0 (inputs ``ut, ua, ue, ur``, mixed to ESC commands) or the
rate plant (:mod:`lpv_sysid.models.rate_plant`: inputs thrust + body-rate setpoints, sent as
SET_ATTITUDE_TARGET).
:func:`check_flight_signals`: the phase-2 signal to be flown against the same gains: every
v_d sample inside the scheduling box, the table inside the design envelope
(:func:`lpv_sysid.signals.excitation.check_design`) and ``kappa |u_e|`` inside the designed
excitation peak. ``lpv_controller_node`` (``signals_file``), ``lpv-sysid fly phase2`` and the
chain's phase 2 run both through :class:`~lpv_sysid.flight.controller.ControllerRuntime`, so
every path refuses the same files with the same words.
:func:`settle_gc`: the garbage-collector policy of the loaded controller.
"""

from __future__ import annotations

import gc

import numpy as np

from lpv_sysid.control.safety import check_closed_loop, check_loop_delay
from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.controller.settings import BOX_MARGIN_MAX_FRACTION, ControllerSettings
from lpv_sysid.io.formats import GainSchedule, load_certified_systems, load_seal_key
from lpv_sysid.models import rate_plant
from lpv_sysid.models.quadrotor import INPUT_NAMES, STATE_NAMES

#: the designs a gains file can hold (:func:`design_of`)
VIRTUAL_ACTUATOR = "virtual_actuator"
RATE_PLANT = rate_plant.DESIGN
#: tolerance of the signal checks (round-off of a table written at the design's peak)
_TOL = 1e-9


def design_of(gs: GainSchedule, label: str) -> str:
    """Which plant the gains were designed for, from their state and input names:
    :data:`VIRTUAL_ACTUATOR` (seed 0 Eq. 14 states, Eq. 7 virtual inputs) or
    :data:`RATE_PLANT` (PX4's rate loop inside, thrust + body-rate setpoints)."""
    states, inputs = tuple(gs.state_names), tuple(gs.input_names)
    if states == tuple(STATE_NAMES) and inputs == tuple(INPUT_NAMES):
        return VIRTUAL_ACTUATOR
    if states == rate_plant.STATE_NAMES and inputs == rate_plant.INPUT_NAMES:
        return RATE_PLANT
    raise ConfigError(
        f"{label}: states {list(states)} / inputs {list(inputs)} are neither the virtual-"
        f"actuator quadrotor's {list(STATE_NAMES)} / {list(INPUT_NAMES)} nor the rate "
        f"plant's {list(rate_plant.STATE_NAMES)} / {list(rate_plant.INPUT_NAMES)}"
    )


def load_flight_schedule(
    settings: ControllerSettings, mix: np.ndarray
) -> tuple[GainSchedule, list]:
    """The gains to fly, after every start-up check of the module docstring; returns the
    schedule and the info lines describing what was checked. ConfigError names the reason."""
    path = settings.gains_file
    label = str(path)
    key = load_seal_key(settings.seal_key_file) if settings.seal_key_file else None
    # structure, law hash (certificate.gains_sha256) and the seal of the whole file
    gs = GainSchedule.load(path, settings.models_file or None, auto_layout=True, key=key)
    design_name = design_of(gs, label)
    gs.check_law_sha256(label)
    systems = load_certified_systems(
        path, gs.certificate, len(gs.state_names), len(gs.input_names), label
    )
    abscissa = check_closed_loop(gs.K, systems, label)
    design = gs.certificate.design
    if design is None:
        raise ConfigError(
            f"{label}: certificate.design missing: the gains do not say which "
            "phase-2 signal they were designed for (reference rates, excitation "
            "peak); synthesize them again with the summary.yaml of the phase-2 signals "
            "(it records the design envelope)"
        )
    if design_name == VIRTUAL_ACTUATOR:
        _check_esc_trims(gs, settings, mix, label)
    width = float(np.min(gs.scheduling.max - gs.scheduling.min))
    if settings.box_margin > BOX_MARGIN_MAX_FRACTION * width:
        raise ConfigError(
            f"lpv_controller: box_margin {settings.box_margin:g} m/s exceeds "
            f"{BOX_MARGIN_MAX_FRACTION:g} of the narrowest box axis ({width:g} m/s, "
            f"{label}): the certificate covers the box only"
        )
    delay_line = check_loop_delay(gs.certificate, settings.loop_delay_s, label)
    n_sys = sum(len(s) for s in systems)
    info = [
        f"gains {path} ({design_name} design): law sha256 "
        f"{(gs.certificate.gains_sha256 or '')[:12]} matches the certificate, the whole file "
        f"its seal{' (keyed)' if key else ''}; closed loop "
        f"stable on {n_sys} certified systems (max Re(eig) {abscissa:.3g}); design envelope "
        f"({design.source or 'certificate.design'}): |dv_d/dt| <= "
        f"{np.round(design.reference_rate, 3).tolist()} m/s^2, |u_e| <= "
        f"{np.round(design.excitation_peak, 4).tolist()}",
        delay_line,
    ]
    if settings.signals_file:
        info.append(check_flight_signals(gs, settings.signals_file, settings.excitation_gain))
    return gs, info


def _check_esc_trims(
    gs: GainSchedule, settings: ControllerSettings, mix: np.ndarray, label: str
) -> None:
    """The ESC limits contain every vertex trim (virtual-actuator design, Eq. 7)."""
    m = gs.K.shape[1]
    if mix.shape != (m, m):
        raise ConfigError(f"{label}: {m} inputs, but the mixer is {mix.shape[0]}x{mix.shape[1]}")
    esc = np.linalg.solve(mix, gs.u0.T).T  # vertex trims as ESC commands (Eq. 7)
    lo, hi = settings.u_esc_min, settings.u_esc_max
    for i, e in enumerate(esc):
        if e.min() < lo or e.max() > hi:
            raise ConfigError(
                f"lpv_controller: ESC limits [{lo:g}, {hi:g}] do not contain the "
                f"trim ESC commands {np.round(e, 4).tolist()} of vertex {i} "
                f"({label}): every command would be clamped"
            )


def check_flight_signals(gs: GainSchedule, signals_file: str, kappa: float) -> str:
    """The phase-2 table ``signals_file`` (``signals.npz`` or its directory) against the gains
    ``gs`` and the excitation multiplier ``kappa`` (seed 0 Eq. 33): every v_d sample inside the
    scheduling box (the certificate covers the box only), the table inside the design envelope
    (:func:`lpv_sysid.signals.excitation.check_design`; the fade is the excitation node's to
    check), and ``kappa max|u_e|`` per channel within the designed excitation peak. Returns
    the info line; ConfigError names the first violation."""
    from pathlib import Path

    from lpv_sysid.signals.excitation import PHASE2_CHANNELS, PHASE2_EXCITATION, check_design
    from lpv_sysid.signals.store import load_npz

    design = gs.certificate.design
    if design is None:  # load_flight_schedule refuses such gains first
        raise ConfigError("certificate.design missing: cannot check the signals")
    path = Path(signals_file)
    if path.is_dir():
        path = path / "signals.npz"
    where = str(path)
    t, u, table_names = load_npz(where)
    names = [str(n) for n in table_names]
    missing = [n for n in PHASE2_CHANNELS + PHASE2_EXCITATION if n not in names]
    if missing:
        raise ConfigError(f"{where}: channel(s) {missing} missing for phase 2")
    lo, hi = gs.scheduling.min, gs.scheduling.max
    for k, n in enumerate(PHASE2_CHANNELS):
        x = u[:, names.index(n)]
        if x.min() < lo[k] - _TOL or x.max() > hi[k] + _TOL:
            raise ConfigError(
                f"{where}: {n} spans [{x.min():.4g}, {x.max():.4g}] m/s, outside the "
                f"scheduling box [{lo[k]:.4g}, {hi[k]:.4g}] m/s the gains are certified on"
            )
    check_design(t, u, names, design, float(design.fade_s), where=where)
    for k, n in enumerate(PHASE2_EXCITATION):
        peak = float(kappa) * float(np.max(np.abs(u[:, names.index(n)])))
        if peak > design.excitation_peak[k] * (1 + _TOL):
            raise ConfigError(
                f"{where}: kappa {kappa:g} x {n} peak = {peak:.4g} exceeds the design "
                f"excitation peak {design.excitation_peak[k]:.4g} (excitation_gain, kappa of "
                "seed 0 Eq. 33, scales the signal the gains' R was designed for)"
            )
    return (
        f"signals {where}: v_d inside the box, within the design envelope, kappa {kappa:g} "
        "x u_e within the designed excitation peak"
    )


def settle_gc() -> None:
    """The GC policy of a running controller (called by the node once the runtime is loaded).

    ``gc.collect()`` then ``gc.freeze()``: everything alive after loading (numpy, the message
    classes, the gains and certificate arrays, the parsed config: ~46,000 tracked objects with
    the stand-in rclpy, more with the real one) moves to the permanent generation, so a full
    collection -- CPython still triggers them when cyclic garbage accumulates, e.g. from the
    executor -- traverses only what was allocated since: measured 7 ms for a full collection
    of the loaded heap before, < 0.01 ms after, i.e. no longer a tick's worth of latency. The
    young-generation thresholds stay CPython's: reference counting frees everything a tick
    allocates (bench_controller_node counted no collection of any generation in 6,245 ticks
    and 13,750 input messages), so a young pass only runs on the executor's own garbage."""
    gc.collect()
    gc.freeze()
