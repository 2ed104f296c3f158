"""One phase-1 run's streams aligned on a uniform grid (:func:`align`, :func:`resample`), its
vertex snapped to the box (:func:`snap_to_box`) and the Table 1 trim row (:func:`trim_row`,
:func:`format_table1`); the method is the :mod:`lpv_sysid.ident.dataprep` docstring."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from lpv_sysid.errors import BagError, ConfigError
from lpv_sysid.ident import derivatives as deriv
from lpv_sysid.ident.dataprep.streams import Streams
from lpv_sysid.ident.vertex import IdentificationConfig, VertexData

log = logging.getLogger(__name__)

TABLE1_COLUMNS = ("u0", "v0", "w0", "phi0", "theta0", "dt0", "da0", "de0", "dr0")
TABLE1_UNITS = ("m/s", "m/s", "m/s", "deg", "deg", "rad/s", "m*rad/s", "m*rad/s", "rad/s")


@dataclass(frozen=True)
class AlignedRun:
    """One run on the common grid plus what identification needs."""

    vertex: VertexData
    Omega: np.ndarray  # (N, 4) on the grid
    euler: np.ndarray  # (N, 3) on the grid
    reference: np.ndarray | None  # (N, 4)
    input_source: str  # "actuator_command" or "rotor_speeds (Eq. 8 inverted)"
    t0: float = 0.0  # absolute time (s, stamp clock) of the first grid sample


# ----------------------------------------------------------------------------- alignment
def _clean(name: str, t: np.ndarray, y: np.ndarray, run: str) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.ndim != 1 or y.shape[0] != t.size:
        raise BagError(f"{run}: topic '{name}' has {t.size} stamps for {y.shape[0]} samples")
    if t.size < 2:
        raise BagError(f"{run}: topic '{name}' has {t.size} sample(s)")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        bad = np.nonzero(~np.isfinite(y).all(axis=tuple(range(1, y.ndim))) | ~np.isfinite(t))[0]
        raise BagError(f"{run}: topic '{name}' has non-finite values at t = {t[bad[0]]:.3f} s")
    order = np.argsort(t, kind="stable")
    if np.any(order != np.arange(t.size)):
        log.warning("%s: topic '%s' stamps out of order, sorted", run, name)
    t, y = t[order], y[order]
    keep = np.r_[True, np.diff(t) > 0]
    return t[keep], y[keep]


def _check_gaps(name: str, t: np.ndarray, a: float, b: float, max_gap: float, run: str) -> None:
    inside = t[(t >= a - max_gap) & (t <= b + max_gap)]
    gaps = np.diff(inside)
    if gaps.size and np.max(gaps) > max_gap:
        k = int(np.argmax(gaps))
        raise BagError(
            f"{run}: topic '{name}' has a {gaps[k]:.3f} s gap at t = {inside[k]:.3f} s "
            f"(max {max_gap:.3f} s): lost link or dropped messages"
        )


def _interp(tg: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Interpolation onto ``tg`` by a cubic spline (``scipy.interpolate.CubicSpline``,
    not-a-knot).  Linear interpolation would low-pass the signal by ``1 - a (1 - a)
    (1 - cos(2 pi f T))`` (``a`` the fractional offset of the grid from the samples): a
    100 Hz stream read 2 ms off its stamps loses 1 % at 6 Hz, which biases the motor constants
    (seed 0 Eq. 8) by more than their standard error; the spline's loss is ``O((2 pi f T)^4)``.
    A stream sampled faster than the grid is first low-passed (zero-phase 4th-order
    Butterworth at 0.4 x the grid rate, ``scipy.signal.sosfiltfilt``) so that its content
    above the grid's Nyquist frequency cannot alias into the identification band (the rate
    controller's command is broadband)."""
    from scipy.interpolate import CubicSpline
    from scipy.signal import butter, sosfiltfilt

    y2 = y.reshape(y.shape[0], -1)
    dt_src = float(np.median(np.diff(t)))
    dt_grid = float(tg[1] - tg[0]) if tg.size > 1 else dt_src
    if dt_src < 0.9 * dt_grid and t.size > 30:
        # filter on the (near-)uniform source grid
        tu = t[0] + dt_src * np.arange(int(np.floor((t[-1] - t[0]) / dt_src)) + 1)
        yu = np.stack([np.interp(tu, t, y2[:, j]) for j in range(y2.shape[1])], axis=1)
        sos = butter(4, 0.4 / dt_grid, fs=1.0 / dt_src, output="sos")
        y2 = sosfiltfilt(sos, yu, axis=0)
        t = tu
    if t.size >= 4:
        out = CubicSpline(t, y2, axis=0, extrapolate=True)(np.clip(tg, t[0], t[-1]))
    else:
        out = np.stack([np.interp(tg, t, y2[:, j]) for j in range(y2.shape[1])], axis=1)
    return out.reshape((tg.size,) + y.shape[1:])


def _first_departure(t: np.ndarray, y: np.ndarray, thr: float) -> float | None:
    dev = np.max(np.abs(y - y[0]), axis=1) if y.ndim == 2 else np.abs(y - y[0])
    idx = np.nonzero(dev > thr)[0]
    return float(t[idx[0]]) if idx.size else None


def resample(s: Streams, sample_rate: float, max_gap: float = 0.25) -> dict[str, np.ndarray]:
    """Steps 1-2 of the module docstring: cleaned streams on one uniform grid.

    Returns ``t`` (absolute, s), ``state`` (N, 9: euler, v, omega), ``Omega`` (N, 4) and, when
    present, ``u``, ``ref``, plus the cleaned raw ``series`` (for event detection).
    """
    run = s.name or "run"
    ts, st = _clean("state", s.t_state, np.concatenate([s.euler, s.v, s.omega], axis=1), run)
    tr, Om = _clean("rotor_speeds", s.t_rotor, s.Omega, run)
    series = {"state": (ts, st), "rotor_speeds": (tr, Om)}
    for nm, t, y in (
        ("actuator_command", s.t_cmd, s.u),
        ("velocity_reference", s.t_ref, s.ref),
        ("excitation", s.t_exc, s.exc),
    ):
        if t is not None and y is not None and len(t):
            series[nm] = _clean(nm, t, y, run)
    if "actuator_command" in series:
        # the command is held (ZOH) from its stamp to the next one: its sample represents the
        # interval, whose centre is half a period later (step 4 of the module docstring)
        tc, uc = series["actuator_command"]
        series["actuator_command"] = (tc + 0.5 * float(np.median(np.diff(tc))), uc)
    core = [k for k in ("state", "rotor_speeds", "actuator_command") if k in series]
    a = max(series[k][0][0] for k in core)
    b = min(series[k][0][-1] for k in core)
    dt = 1.0 / sample_rate
    if b - a < 2 * dt:
        raise BagError(f"{run}: topics {core} do not overlap in time")
    for nm in core:
        _check_gaps(nm, series[nm][0], a, b, max_gap, run)
    tr = series["rotor_speeds"][0]
    if abs(float(np.median(np.diff(tr))) - dt) < 0.01 * dt:
        # rotor telemetry at the grid rate is not anti-alias filtered (it arrives sampled):
        # put the grid on its stamps so that it is not interpolated between aliased samples
        a = float(tr[np.searchsorted(tr, a - 1e-9)])
    tg = a + dt * np.arange(int(np.floor((b - a) / dt)) + 1)
    out = {
        "t": tg,
        "state": _interp(tg, *series["state"]),
        "Omega": _interp(tg, *series["rotor_speeds"]),
        "series": series,
    }
    if "actuator_command" in series:
        out["u"] = _interp(tg, *series["actuator_command"])
    if "velocity_reference" in series:
        out["ref"] = _interp(tg, *series["velocity_reference"])
    return out


def align(s: Streams, cfg: IdentificationConfig, params=None, max_gap: float = 0.25) -> AlignedRun:
    """Resample a run onto the common grid and segment it (module docstring, steps 1-6)."""
    from lpv_sysid.models.quadrotor import QuadrotorParams, mixer

    params = params or (
        QuadrotorParams.from_dict(cfg.quadrotor) if cfg.quadrotor else QuadrotorParams()
    )
    run = s.name or "run"
    s, origin = _rebased(s)
    g = resample(s, cfg.sample_rate, max_gap)
    series, tg, sg, Og = g["series"], g["t"], g["state"], g["Omega"]
    dt = 1.0 / cfg.sample_rate
    mix = mixer(params.arm_length)
    delta = Og @ mix.T
    x = np.concatenate([sg[:, 0:2], sg[:, 3:9], delta], axis=1)
    if "u" in g:
        u = g["u"]
        source = "actuator_command"
        # the input the rotors act on, Eq. (8): the ESC clip applied to the command samples
        # before resampling (a clip after the anti-alias filter would round the corners)
        tc, uc = series["actuator_command"]
        mi = np.linalg.inv(mix)
        u_eff = _interp(tg, tc, np.clip(uc @ mi.T, 0.0, 1.0) @ mix.T)
    else:
        # Eq. (8) inverted: u = Mix u_ESC = (delta' + a delta) / b (module docstring, step 4)
        _, ddelta = deriv.smooth_and_differentiate(delta, dt, cfg.derivatives)
        u = (ddelta + params.a_omega * delta) / params.b_omega
        u_eff = u
        source = "rotor_speeds (Eq. 8 inverted)"
        log.warning("%s: no actuator_command; input reconstructed from rotor speeds", run)
    ref = g.get("ref")
    # excitation start
    t_exc = s.t_excite
    how = "given"
    if t_exc is None and "excitation" in series:
        t_e, y_e = series["excitation"]
        t_exc, how = _first_departure(t_e, y_e, cfg.excitation_threshold), "excitation topic"
    if t_exc is None and "velocity_reference" in series:
        t_r, y_r = series["velocity_reference"]
        t_exc, how = _first_departure(t_r, y_r, 1e-3), "velocity reference"
    if t_exc is None:
        t_exc, how = tg[0] + cfg.trim_duration, "configured trim_duration"
    trim = (max(tg[0], t_exc - cfg.trim_duration), t_exc)
    if trim[1] - trim[0] < min(1.0, 0.5 * cfg.trim_average):
        raise BagError(
            f"{run}: only {trim[1] - trim[0]:.2f} s of trim before the excitation at "
            f"{t_exc:.2f} s ({how}); need >= {min(1.0, 0.5 * cfg.trim_average):.2f} s"
        )
    fit = (t_exc, tg[-1] + dt)
    if fit[1] - fit[0] < cfg.min_fit_duration + 2 * cfg.edge:
        raise BagError(
            f"{run}: excitation segment is {fit[1] - fit[0]:.2f} s long, need >= "
            f"{cfg.min_fit_duration + 2 * cfg.edge:.2f} s (bag too short or truncated)"
        )
    if ref is None:
        raise BagError(
            f"{run}: topic 'velocity_reference' missing: the scheduling vertex is unknown"
        )
    in_trim = (tg >= trim[0]) & (tg < trim[1])
    v_d = ref[in_trim, :3].mean(axis=0)
    log.info("%s: excitation at %.2f s (%s), v_d = %s", run, t_exc, how, np.round(v_d, 3).tolist())
    vd = VertexData(
        tg - tg[0],
        x,
        u,
        v_d,
        (trim[0] - tg[0], trim[1] - tg[0]),
        (fit[0] - tg[0], fit[1] - tg[0]),
        run,
        u_eff=u_eff,
        motor_identifiable=source == "actuator_command" and not s.rotor_estimated,
    )
    return AlignedRun(vd, Og, sg[:, 0:3], ref, source, float(tg[0]) + origin)


def _rebased(s: Streams) -> tuple[Streams, float]:
    """``s`` with its times counted from a whole second before its first state sample, and
    that origin (s). Wall-clock (epoch) stamps are ~1.8e9 s, where float64 resolves only
    2.4e-7 s: a uniform grid built on them is not uniform to the 1e-8 s identification
    checks; relative times are exact enough."""
    import dataclasses

    if s.t_state is None or not len(s.t_state):
        return s, 0.0
    origin = float(np.floor(np.min(s.t_state)))
    if abs(origin) < 1e6:  # simulation / boot time: already exact
        return s, 0.0

    def sh(t):
        return None if t is None else np.asarray(t, dtype=float) - origin

    return (
        dataclasses.replace(
            s,
            t_state=sh(s.t_state),
            t_rotor=sh(s.t_rotor),
            t_cmd=sh(s.t_cmd),
            t_ref=sh(s.t_ref),
            t_exc=sh(s.t_exc),
            t_excite=None if s.t_excite is None else float(s.t_excite) - origin,
        ),
        origin,
    )


def snap_to_box(v_d: np.ndarray, cfg: IdentificationConfig, tol: float = 0.25) -> np.ndarray:
    """The box corner (or the centre, for the hover validation run) nearest to a measured
    reference, so vertices can be matched exactly; refuses references far from both."""
    lo, hi = np.asarray(cfg.vmin), np.asarray(cfg.vmax)
    cands = [np.where(np.asarray(bits) == 1, hi, lo) for bits in np.ndindex(*(2,) * lo.size)]
    cands.append(0.5 * (lo + hi))
    d = [np.max(np.abs(v_d - c)) for c in cands]
    k = int(np.argmin(d))
    if d[k] > tol:
        raise ConfigError(
            f"velocity reference {np.round(v_d, 3).tolist()} is neither a box vertex nor "
            f"the centre of [{lo.tolist()}, {hi.tolist()}]"
        )
    return cands[k]


def trim_row(x0: np.ndarray) -> list[float]:
    """Seed 0 Table 1 columns from an equilibrium state (angles in degrees)."""
    return [
        float(x0[2]),
        float(x0[3]),
        float(x0[4]),
        float(np.degrees(x0[0])),
        float(np.degrees(x0[1])),
        *[float(v) for v in x0[8:12]],
    ]


def format_table1(rows: Sequence[tuple[Sequence[float], Sequence[float]]]) -> str:
    """Seed 0 Table 1: ``rows`` of (vertex v_d, Table-1 values)."""
    head = f"{'Vertex':>18} " + " ".join(f"{c:>8}" for c in TABLE1_COLUMNS)
    units = f"{'[m/s]':>18} " + " ".join(f"{'[' + u + ']':>8}" for u in TABLE1_UNITS)
    lines = [head, units]
    for vd, vals in rows:
        vtx = "[" + " ".join(f"{c:+g}" for c in vd) + "]"
        lines.append(
            f"{vtx:>18} " + " ".join(f"{v:8.2f}" if abs(v) < 100 else f"{v:8.1f}" for v in vals)
        )
    return "\n".join(lines)
