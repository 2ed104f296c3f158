"""PX4 bags -> :class:`~lpv_sysid.ident.nonlinear.Px4Record` for the PX4 variant of seed 0
Eq. (6) (``ident.nonlinear.px4_model``; what the record holds and why:
``ident.nonlinear.px4_data``).

``state``, ``rotor_speeds`` (estimated from PX4's motor outputs) and ``imu`` of one rosbag2
directory, cut to the longest stretch without a gap in any of them, resampled onto one
uniform grid (:func:`~lpv_sysid.ident.dataprep.alignment.resample`; the IMU by a cubic
spline), with the smoothed specific force and angular acceleration.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

import numpy as np

from lpv_sysid.errors import BagError, ConfigError
from lpv_sysid.ident.dataprep.alignment import resample
from lpv_sysid.ident.dataprep.streams import streams_from_bag

log = logging.getLogger(__name__)


def _imu(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(t, specific force FRD (N, 3)) of the bag's ``imu`` topic."""
    from lpv_sysid.io import bag as iobag
    from lpv_sysid.io.messages import imu_from_msg

    topics = [t for t in iobag.topic_info(str(path)) if t.rstrip("/").split("/")[-1] == "imu"]
    if len(topics) != 1:
        raise BagError(f"{path}: needs exactly one 'imu' topic (specific force), found {topics}")
    rows = iobag.read_bag(str(path), topics=topics)[topics[0]]
    if len(rows) < 10:
        raise BagError(f"{path}: topic 'imu' has {len(rows)} messages")
    samples = [imu_from_msg(m) for _, m in rows]
    t = np.array([s.t for s in samples])
    f = np.array([s.specific_force for s in samples])
    order = np.argsort(t, kind="stable")
    t, f = t[order], f[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return t[keep], f[keep]


def _longest_span(streams: list[np.ndarray], max_gap: float) -> tuple[float, float]:
    """The longest interval covered by every stream (sorted stamps) without a gap longer
    than ``max_gap`` in any of them (a stalled link cuts the record, not the flight)."""
    a = max(float(t[0]) for t in streams)
    b = min(float(t[-1]) for t in streams)
    holes = []
    for t in streams:
        d = np.diff(t)
        for k in np.flatnonzero(d > max_gap):
            holes.append((float(t[k]), float(t[k + 1])))
    holes.sort()
    best, start = (a, a), a
    for lo, hi in holes + [(b, b)]:
        if hi <= start:
            continue
        end = min(lo, b)
        if end - start > best[1] - best[0]:
            best = (start, end)
        start = max(start, hi)
        if start >= b:
            break
    return best


def _cut(s, a: float, b: float):
    """Streams ``s`` restricted to [a, b]."""
    ks = (s.t_state >= a) & (s.t_state <= b)
    kr = (s.t_rotor >= a) & (s.t_rotor <= b)
    return dataclasses.replace(
        s,
        t_state=s.t_state[ks],
        euler=s.euler[ks],
        v=s.v[ks],
        omega=s.omega[ks],
        t_rotor=s.t_rotor[kr],
        Omega=s.Omega[kr],
    )


def px4_record(
    bag: str | Path,
    params: Any,
    sample_rate: float = 100.0,
    deriv_cfg=None,
    edge_s: float = 0.5,
    max_gap: float = 0.25,
) -> Any:
    """:class:`Px4Record` of one rosbag2 directory with ``state``, ``rotor_speeds`` and
    ``imu`` (a phase-2 or phase-1 bag of the PX4 bridge). ``params``: the airframe whose
    ``a_omega``, ``b_omega``, ``omega_min``, ``omega_max`` the bridge's estimate used."""
    from scipy.interpolate import CubicSpline

    from lpv_sysid.ident import derivatives as dv

    bag = Path(bag)
    s = streams_from_bag(bag)
    t_imu, f_imu = _imu(bag)
    origin = float(np.floor(np.min(s.t_state)))
    s = dataclasses.replace(
        s,
        t_state=s.t_state - origin,
        t_rotor=s.t_rotor - origin,
        t_cmd=None,
        u=None,
        t_ref=None,
        ref=None,
        t_exc=None,
        exc=None,
    )
    t_imu = t_imu - origin
    a, b = _longest_span([np.sort(s.t_state), np.sort(s.t_rotor), t_imu], max_gap)
    if b - a < 2 * edge_s + 2.0:
        raise BagError(
            f"{bag}: no stretch of {2 * edge_s + 2.0:.1f} s without a gap > {max_gap} s"
        )
    if a > float(np.min(s.t_state)) + 0.5 or b < float(np.max(s.t_state)) - 0.5:
        log.warning("%s: gaps in the streams: using %.1f .. %.1f s only", bag, a, b)
    s = _cut(s, a, b)
    g = resample(s, sample_rate, max_gap)
    t = g["t"]
    inside = (t >= t_imu[0]) & (t <= t_imu[-1])
    if inside.sum() < 20:
        raise BagError(f"{bag}: imu does not overlap state and rotor_speeds")
    t = t[inside]
    st = g["state"][inside]
    Om = g["Omega"][inside]
    f_raw = CubicSpline(t_imu, f_imu, axis=0)(t)
    cfg = deriv_cfg or dv.DerivativeConfig()
    dt = float(t[1] - t[0])
    n_edge = int(round(edge_s / dt))
    if t.size <= 2 * n_edge + 20:
        raise ConfigError(f"{bag}: {t.size} samples: too short for edges of {edge_s} s")
    omega = st[:, 6:9]
    _, omega_dot = dv.smooth_and_differentiate(omega, dt, cfg)
    lim = (Om <= params.omega_min * 1.001) | (Om >= params.omega_max * 0.999)
    at_limit = float(np.mean(np.any(lim, axis=1)))
    if at_limit > 0.01:
        log.warning(
            "%s: %.1f %% of samples have a rotor estimate at its clip [%g, %g] rad/s: the "
            "motor output there is not recoverable",
            bag,
            100 * at_limit,
            params.omega_min,
            params.omega_max,
        )
    from lpv_sysid.ident.nonlinear import Px4Record

    return Px4Record(
        name=f"{bag.parent.name}/{bag.name}",
        t=t,
        v=st[:, 3:6],
        omega=omega,
        x_motor=Om * (params.a_omega / params.b_omega),
        f=dv.smooth(f_raw, dt, cfg),
        omega_dot=omega_dot,
        a_omega=float(params.a_omega),
        smoother=lambda a: dv.smooth(a, dt, cfg),
        keep=slice(n_edge, t.size - n_edge),
        at_limit=at_limit,
        motor_period=float(np.median(np.diff(s.t_rotor))),
    )
