"""What gamma bounds: the parts of a phase-2 run's ``z = Q^-1 (v - v_d)`` (seed 0 Eqs. 18, 29).

``z`` holds the response to the excitation ``u_e`` (the only part Lemma 1 bounds, Eq. 29), the
lag in following ``v_d`` and the equilibrium offset ``Q^-1 (v0(v_d) - v_d)``
(:func:`offset_output`). :func:`gain_decomposition` reports the norm of each part against
``||kappa u_e||_2``; :func:`decompose_eq33` finds the excitation part of an Eq. (33) run by exact
superposition (the model is linear in the excitation).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from lpv_sysid.sim.closed_loop import (
    VELOCITY_INDEX,
    ClosedLoopConfig,
    ClosedLoopResult,
    ReferenceSignals,
    l2_norm,
    simulate_eq33,
)
from lpv_sysid.sim.phase2.inputs import Phase2Config, Phase2Problem


def offset_output(problem: "Phase2Problem", v_d: np.ndarray) -> np.ndarray:
    """``Q^-1 (v0(v_d) - v_d)`` (N, 3): the equilibrium offset part of z, with ``v0(v_d)`` the
    velocity of the scheduled equilibrium (multilinear weights of the vertex ``x0``, Eq. 21)."""
    from lpv_sysid.models.lpv import multilinear_weights

    vi = list(VELOCITY_INDEX)
    v0 = np.array(
        [
            multilinear_weights(np.asarray(vd, dtype=float), problem.vmin, problem.vmax)[0]
            @ problem.x0[:, vi]
            for vd in np.asarray(v_d, dtype=float)
        ]
    )
    return np.linalg.solve(np.asarray(problem.Q, dtype=float), (v0 - v_d).T).T


def gain_decomposition(
    t: np.ndarray,
    z: np.ndarray,
    ue: np.ndarray,
    z_offset: np.ndarray,
    z_e: Optional[np.ndarray],
    method: str,
    **info,
) -> dict:
    """Norms of the parts of ``z`` (module docstring) and their ratios to ``||kappa u_e||_2``:
    ``excitation`` (``z_e``; its ratio is the gain gamma bounds), ``offset``, ``tracking`` =
    ``z - z_offset - z_e`` and ``total``.  The norms are not additive (the parts overlap in
    time)."""
    ue_norm = l2_norm(t, ue)

    def part(y):
        n = l2_norm(t, y)
        return {"z_norm": float(n), "ratio": float(n / ue_norm) if ue_norm > 0 else None}

    out = {"method": method, "ue_norm": float(ue_norm), "total": part(z), "offset": part(z_offset)}
    if z_e is None:
        out["excitation"] = {"z_norm": None, "gain": None}
        out["tracking_and_excitation"] = part(z - z_offset)
    else:
        ex = part(z_e)
        out["excitation"] = {"z_norm": ex["z_norm"], "gain": ex["ratio"]}
        out["tracking"] = part(z - z_offset - z_e)
    out.update(info)
    return out


def decompose_eq33(
    problem: "Phase2Problem",
    signals: ReferenceSignals,
    res: ClosedLoopResult,
    cfg: "Phase2Config",
    law=None,
    moving_equilibrium: bool = True,
) -> dict:
    """:func:`gain_decomposition` of an Eq. (33) run by exact superposition (the model is
    linear in the excitation).  With the moving equilibrium and the Eq. (31) law, started at
    ``x0(v_d(0))``, the unexcited solution is ``x0(v_d(t))`` itself (the ``x0'`` term of Eq. 34
    carries it), so ``z - z_offset`` is ``z_e`` and there is no tracking part; otherwise (the
    feedforward law without ``x0'``) the same closed loop with ``-u_e`` gives
    ``z(+) - z(-) = 2 z_e``."""
    z_off = offset_output(problem, res.v_d)
    if moving_equilibrium and law is None:
        return gain_decomposition(
            res.t,
            res.z,
            res.ue,
            z_off,
            res.z - z_off,
            "superposition (exact: the unexcited Eq. 33 run stays at x0(v_d))",
        )
    mirrored = ReferenceSignals(signals.t, signals.v_d, -signals.u_e)
    kw = {} if law is None else {"law": law}
    neg = simulate_eq33(
        problem.scheduled(),
        mirrored,
        problem.R,
        problem.Q,
        problem.gamma,
        ClosedLoopConfig(kappa=cfg.kappa, method=cfg.eq33_method),
        moving_equilibrium=moving_equilibrium,
        **kw,
    )
    z_e = 0.5 * (res.z - neg.z)
    return gain_decomposition(
        res.t, res.z, res.ue, z_off, z_e, "superposition (exact: the same run with -u_e)"
    )
