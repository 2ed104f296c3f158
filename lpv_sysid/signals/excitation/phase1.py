"""The phase-1 reference of seed 0 Sec. IV: the 4-axis multisine (:func:`phase1_signals`) and
the vertex reference with it superposed (:func:`phase1_reference`)."""

from __future__ import annotations

from typing import Sequence

from lpv_sysid.signals.excitation.player import ExcitationCore


def phase1_signals(
    duration: float = 30.0,
    band: Sequence[float] = (0.2, 2.0),
    peaks: Sequence[float] = (1.0, 1.0, 0.5, 0.5),
    sample_rate: float = 50.0,
):
    """Design the phase-1 4-axis multisine (seed 0 Sec. IV) with channels
    ``u_ref, v_ref, w_ref, r_ref`` scaled to ``peaks`` (m/s, m/s, m/s, rad/s), flat spectrum
    in ``band`` Hz, one period of ``duration`` s; the optimiser options of ``PHASE1_DEFAULT``.
    Returns a :class:`~lpv_sysid.signals.multisine.SignalSet` for :func:`phase1_reference`."""
    from lpv_sysid.signals.multisine import PHASE1_DEFAULT, SignalsConfig, design

    d = {
        **PHASE1_DEFAULT,
        "duration": duration,
        "sample_rate": sample_rate,
        "groups": [{**PHASE1_DEFAULT["groups"][0], "band": list(band), "peak": list(peaks)}],
    }
    return design(SignalsConfig.from_dict(d, where="phase1_signals"))


def phase1_reference(
    vertex_velocity: Sequence[float],
    signals=None,
    *,
    trim: float = 10.0,
    ramp: float = 0.0,
    yaw_rate_offset: float = 0.0,
) -> ExcitationCore:
    """Phase-1 reference of seed 0 Sec. IV for one vertex: ``trim`` seconds at the constant
    vertex velocity, then one 30 s period of the 4-axis multisine (u, v, w, yaw rate) on top.

    ``vertex_velocity``: (3,) FRD body velocity of the vertex, m/s.
    ``signals``: a :class:`~lpv_sysid.signals.multisine.SignalSet` with channels
    ``u_ref, v_ref, w_ref, r_ref`` (:func:`phase1_signals`) or a ``(t, u, names)`` tuple
    (e.g. from :func:`lpv_sysid.signals.store.load_npz`); ``None`` designs
    ``phase1_signals()`` (~0.5 s; design once and pass it when flying several vertices).
    Returns an :class:`ExcitationCore` with ``start_time = trim``: call
    ``core.evaluate(t) -> (v_ref (K,3), r_ref (K,), u_e (K,4))`` on a time grid, or
    ``core.sample(t)`` step by step; the excitation ends at ``core.end_time`` (= trim + 30 s
    + 2 ramp), after which the output is the vertex velocity again.
    """
    if signals is None:
        signals = phase1_signals()
    if hasattr(signals, "u") and hasattr(signals, "names"):
        t, u, names = signals.t, signals.u, signals.names
    else:
        t, u, names = signals
    return ExcitationCore.phase1(
        t,
        u,
        names,
        start_time=trim,
        vertex_velocity=vertex_velocity,
        ramp=ramp,
        yaw_rate_offset=yaw_rate_offset,
    )
