"""What the PX4 chain's flights measured (:mod:`lpv_sysid.flight.chain`).

The u_e -> z gain of seed 0 Eqs. (26)-(29) on flight data (:func:`excitation_gain`), the
tracking and saturation figures of a phase-2 flight (:func:`analyse_phase2`) and the torque error
of a rate-loop inversion on flown body rates (:func:`inversion_error`, the measurement behind the
choice of the rate plant).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Mapping

import numpy as np

from lpv_sysid.errors import ConfigError

if TYPE_CHECKING:
    from lpv_sysid.flight.phase2.options import Phase2Options


def excitation_gain(
    tsig: np.ndarray,
    z: np.ndarray,
    u_e: np.ndarray,
    fs: float,
    lags_s: float = 1.0,
    f_cut: float = 0.3,
    ridge: float = 1e-6,
) -> dict:
    """The u_e -> z gain of seed 0 Eqs. (26)-(29) on flight data (uniform grid ``tsig`` at
    ``fs``), not mixed with tracking error: the part z_e of z explained by the excitation through
    the FIR regression of :func:`lpv_sysid.sim.closed_loop.excitation_fir.excitation_response_fir`.
    Returns the energy ratio ||z_e||_2 / ||u_e||_2 over the fitted window (the flown signal's Eq.
    29 ratio), the FIR's peak gain at the excited frequencies (a lower estimate of the H-inf norm
    the certificate bounds), the fit's R^2 and the window (rows of ``tsig``)."""
    from lpv_sysid.sim.closed_loop import excitation_response_fir

    try:
        z_e, info = excitation_response_fir(tsig, z, u_e, f_cut, lags_s, fs, ridge)
    except ConfigError as exc:
        return {"method": "FIR regression", "error": str(exc)}
    half = 0.5 / fs
    a = int(np.searchsorted(tsig, info["window_s"][0] - half))
    b = int(np.searchsorted(tsig, info["window_s"][1] + half))
    Ee = float((u_e[a:b] ** 2).sum() / fs)
    Ez = float((z_e[a:b] ** 2).sum() / fs)
    return {
        "method": (
            f"FIR regression of high-passed z (> {f_cut:g} Hz) on u_e, {info['lags']} lags "
            f"({lags_s:g} s)"
        ),
        "energy_ratio": math.sqrt(Ez / Ee) if Ee > 0 else float("nan"),
        "fir_peak_gain": info["fir_peak_gain"],
        "fit_r2": info["fit_r2"],
        "excitation_energy": Ee,
        "window": [a, b],
    }


def inversion_error(
    t: np.ndarray,
    omega: np.ndarray,
    rate_p=(0.15, 0.15, 0.2),
    delays=(0.01, 0.02, 0.04),
    arm_length: float = 0.225,
    design_magnitudes=(0.01, 0.01, 0.05),
) -> dict:
    """How closely the rate-loop inversion of
    :class:`~lpv_sysid.mavlink.bridge.transport.AttitudeRateTransport`
    (omega_sp = omega_measured + tau / K_p) can make PX4 apply a commanded virtual torque,
    measured on flown body rates ``omega`` (N, 3) at times ``t``.

    PX4's proportional term then produces K_p (omega_sp - omega_now) = tau + K_p (omega(t - d) -
    omega(t)) with d the age of the telemetry the command was computed from (link + loop); the
    second term is the torque error (PX4's own I/D/FF terms come on top). Returned per delay:
    the rms of K_p (omega(t - d) - omega(t)) in PX4's normalised torque units, and the ratio to
    the virtual torques of the seed's design magnitudes (Delta_a, Delta_e, Delta_r of
    config/signals_phase2.yaml -> tau = u / (4 s) for roll/pitch, u / 4 for yaw, s = arm
    sqrt(2)/2). Ratios >= 1: the error is as large as the commanded input."""
    t = np.asarray(t, dtype=float)
    omega = np.asarray(omega, dtype=float)
    dt = 0.002
    g = np.arange(t[0], t[-1], dt)
    w = np.column_stack([np.interp(g, t, omega[:, k]) for k in range(3)])
    kp = np.asarray(rate_p, dtype=float)
    s = arm_length * math.sqrt(2.0) / 2.0
    da, de, dr = design_magnitudes
    tau = np.array([da / (4 * s), de / (4 * s), dr / 4.0])
    rows = []
    for d in delays:
        k = max(1, int(round(d / dt)))
        e = kp * np.sqrt(((w[k:] - w[:-k]) ** 2).mean(axis=0))
        rows.append(
            {
                "delay_s": float(d),
                "torque_error_rms": e.tolist(),
                "ratio_to_design_torque": (e / tau).tolist(),
            }
        )
    return {
        "rate_p": kp.tolist(),
        "design_torque": tau.tolist(),
        "omega_rms": np.sqrt((w**2).mean(axis=0)).tolist(),
        "by_delay": rows,
    }


def analyse_phase2(arr: Mapping[str, np.ndarray], gs, gamma: float, opts: Phase2Options) -> dict:
    """Tracking RMS per axis, measured u_e -> z gain (``excitation_gain``) vs gamma, saturation."""
    tsig = arr["tsig"]
    keep = tsig >= 0
    if keep.sum() < 20:
        return {"analysis": "no signal samples"}
    t = arr["t"][keep]
    x, vd, ue = arr["x"][keep], arr["v_d"][keep], arr["u_e"][keep]
    e = x[:, 2:5] - vd
    fs = 1.0 / float(np.median(np.diff(t)))
    Qinv = np.linalg.inv(np.asarray(gs.Q, dtype=float))
    z = e @ Qinv.T
    # resample on a uniform grid (the loop is paced by telemetry; jitter under load)
    tg = np.arange(t[0], t[-1], 1.0 / fs)
    zi = np.column_stack([np.interp(tg, t, z[:, k]) for k in range(z.shape[1])])
    uei = np.column_stack([np.interp(tg, t, ue[:, k]) for k in range(ue.shape[1])])
    gain = excitation_gain(tg - tg[0], zi, uei, fs)
    dt = np.diff(t, prepend=t[0])
    raw = math.sqrt(
        float((z**2 * dt[:, None]).sum()) / max(float((ue**2 * dt[:, None]).sum()), 1e-300)
    )
    sent, u = arr["sent"][keep], arr["u"][keep]
    clipped = int(np.any(np.abs(sent - u) > 1e-9, axis=1).sum())
    return {
        "tracking_rms": {a: float(np.sqrt(np.mean(e[:, k] ** 2))) for k, a in enumerate("uvw")},
        "tracking_max": {a: float(np.max(np.abs(e[:, k]))) for k, a in enumerate("uvw")},
        "reference_rms": {a: float(np.sqrt(np.mean(vd[:, k] ** 2))) for k, a in enumerate("uvw")},
        "gain_u_e_to_z": {
            **gain,
            "gamma": float(gamma),
            "within_gamma": bool(
                gain.get("fir_peak_gain", math.inf) <= gamma
                and gain.get("energy_ratio", math.inf) <= gamma
            ),
        },
        "raw_ratio_mixed_with_tracking": raw,
        "control_rate_hz": fs,
        "flown_signal_s": float(t[-1] - t[0]),
        "commands_clipped": clipped,
        "commands": int(len(t)),
    }


def loop_latency(t_state, t_sent) -> dict:
    """State-stamp -> setpoint-sent latency of the loop [ms]: ``t_sent - t_state`` per command
    (``t_state`` the stamp of the state sample the command was computed on, as the command's
    header carries it with ``tick_source: state``; ``t_sent`` when it went to the link, the
    bag's log time of ``actuator_command``): count, p50, p99, max. It is the loop delay the
    certificate's delay bound must cover."""
    d = (np.asarray(t_sent, dtype=float) - np.asarray(t_state, dtype=float)) * 1e3
    d = d[np.isfinite(d)]
    if d.size == 0:
        return {"commands": 0}
    return {
        "commands": int(d.size),
        "p50": float(np.percentile(d, 50)),
        "p99": float(np.percentile(d, 99)),
        "max": float(d.max()),
    }


def latency_from_bag(bag, topic: str = "actuator_command") -> dict:
    """:func:`loop_latency` from a phase-2 bag: per ``actuator_command`` message its log time
    (when ``fly phase2`` sent it to the link; under ``ros2 launch`` when the data logger received
    it) minus its header stamp (the stamp of the state sample it was computed on, controller
    ``tick_source: state``). The same function for the bag of either path."""
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io.messages import TOPIC_NAMESPACE, stamp_ns_of

    name = next(
        (n for n in iobag.topic_info(str(bag)) if n.rsplit("/", 1)[-1] == topic),
        f"{TOPIC_NAMESPACE}/{topic}",
    )
    rows = iobag.read_bag(str(bag), topics=[name])[name]
    if not rows:
        return {"commands": 0}
    log_ns = np.array([r[0] for r in rows], dtype=np.int64)
    stamp_ns = np.array([stamp_ns_of(r[1]) for r in rows], dtype=np.int64)
    return loop_latency(stamp_ns * 1e-9, log_ns * 1e-9) | {"source": f"{bag}:{name}"}
