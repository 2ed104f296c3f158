"""Start-up of the flight controller: what happens once, before any command can exist.

:func:`load_flight_schedule`: the gains file is validated (io/formats), the law it holds must
hash to ``certificate.gains_sha256`` (the K that flies is the K that was certified), every
``A_ij + B_ij K_i`` of the certified systems in the sidecar must be Hurwitz (eigenvalues only,
milliseconds), the certificate must carry the design envelope of the phase-2 signal, and the
ESC limits must contain every vertex trim; any failure refuses to start, naming the reason.
:func:`settle_gc`: the garbage-collector policy of the loaded controller.
"""

from __future__ import annotations

import gc

import numpy as np

from lpv_sysid.control.safety import check_closed_loop, check_loop_delay, loop_delay_s
from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.controller.settings import BOX_MARGIN_MAX_FRACTION, ControllerSettings
from lpv_sysid.io.formats import GainSchedule, load_certified_systems


def load_flight_schedule(
    settings: ControllerSettings, mix: np.ndarray
) -> tuple[GainSchedule, list]:
    """The gains to fly, after every start-up check of the module docstring; returns the
    schedule and the info lines describing what was checked. ConfigError names the reason."""
    path = settings.gains_file
    label = str(path)
    gs = GainSchedule.load(path, settings.models_file or None)
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
    width = float(np.min(gs.scheduling.max - gs.scheduling.min))
    if settings.box_margin > BOX_MARGIN_MAX_FRACTION * width:
        raise ConfigError(
            f"lpv_controller: box_margin {settings.box_margin:g} m/s exceeds "
            f"{BOX_MARGIN_MAX_FRACTION:g} of the narrowest box axis ({width:g} m/s, "
            f"{label}): the certificate covers the box only"
        )
    delay_line = check_loop_delay(
        gs.certificate,
        loop_delay_s(
            settings.tick_source,
            settings.rate_hz,
            settings.state_rate_hz,
            settings.input_latency_s,
        ),
        label,
    )
    n_sys = sum(len(s) for s in systems)
    info = [
        f"gains {path}: law sha256 {(gs.certificate.gains_sha256 or '')[:12]} matches the "
        f"certificate; closed loop stable on {n_sys} certified systems (max Re(eig) "
        f"{abscissa:.3g}); design envelope ({design.source or 'certificate.design'}): "
        f"|dv_d/dt| <= {np.round(design.reference_rate, 3).tolist()} m/s^2, |u_e| <= "
        f"{np.round(design.excitation_peak, 4).tolist()}",
        delay_line,
    ]
    return gs, info


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
