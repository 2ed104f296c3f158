"""How far the multilinear interpolation of the vertex models (seed 0 Eq. 21) is from the
identified dynamics between the vertices (issue 20 item 2), measured with the identified models
themselves.

Each vertex's ``taylor2`` model is the identified second-order model of Eq. (6) -- exact in its
known rigid-body part (gravity, kinematics, the attitude the trim needs) and in its quadratic
remainders -- so it can be re-expanded at any scheduling point ``v``
(:attr:`lpv_sysid.ident.equation_error.Fit.expand`), with its own delta-method uncertainty
(larger the further ``v`` is from where it was flown). At grid points ``v_g`` of the box (centre,
face centres, edge midpoints, the 8 points halfway to the corners) the model of the nearest
vertex gives an interval ``A_i(v_g) +/- q std_i(v_g)`` (``q`` the Sidak quantile of the joint
probability over all elements) that holds the plant; the interpolated set there is
``sum_j alpha_j A_j +/- sum_j alpha_j h_j`` (``h_j`` the stored half-widths). The pad

    pad = max_g max(0, |A_i(v_g) - sum_j alpha_j A_j| + q std_i(v_g) - sum_j alpha_j h_j)

per element of ``[A, B]``, added to every vertex's half-width, makes the interpolated set contain
those intervals at every grid point. It is measured on a grid, not proven between its points.
"""

from __future__ import annotations

import itertools
from typing import Optional, Sequence

import numpy as np

#: grid of the pad in box coordinates t in [0, 1]^3: centre, face centres, edge midpoints, and
#: the points halfway from the centre to each corner (27 points)
GRID_T = tuple(
    sorted(
        {
            tuple(p)
            for p in itertools.product((0.0, 0.5, 1.0), repeat=3)
            if sum(c == 0.5 for c in p) >= 1
        }
        | {tuple(p) for p in itertools.product((0.25, 0.75), repeat=3)}
    )
)


def _weights(t: np.ndarray, corners: np.ndarray) -> np.ndarray:
    return np.array([np.prod(np.where(c > 0.5, t, 1.0 - t)) for c in corners])


def interpolation_pad(results: Sequence, probability: float) -> Optional[dict]:
    """``meta.interpolation`` of vertex_models.yaml (module docstring) for the vertex
    ``results`` (VertexResult) of a full box (2^n corners, every fit with ``expand``); None
    otherwise."""
    from scipy.stats import norm, t

    S = np.array([np.asarray(r.scheduling, dtype=float) for r in results])
    if S.ndim != 2 or len(results) != 2 ** S.shape[1]:
        return None
    if any(getattr(r.fit, "expand", None) is None for r in results):
        return None
    vmin, vmax = S.min(axis=0), S.max(axis=0)
    if np.any(vmax <= vmin):
        return None
    corners = (S - vmin) / (vmax - vmin)
    p = sum(len(r.uncertain.intervals) for r in results)
    a = 1.0 - probability ** (1.0 / max(p, 1))
    dof = results[0].fit.dof
    q = float(norm.isf(a / 2) if dof is None or not np.isfinite(dof) else t.isf(a / 2, dof))
    AB = [np.concatenate([r.fit.A, r.fit.B], axis=1) for r in results]
    half = []
    for r in results:
        h = np.zeros_like(AB[0])
        for iv in r.uncertain.intervals:
            c = iv.col if iv.matrix == "A" else r.fit.A.shape[1] + iv.col
            h[iv.row, c] = 0.5 * (iv.upper - iv.lower)
        half.append(h)
    pad = np.zeros_like(AB[0])
    worst_at = None
    for tg in GRID_T:
        tv = np.asarray(tg)
        v = vmin + tv * (vmax - vmin)
        w = _weights(tv, corners)
        interp = sum(wi * m for wi, m in zip(w, AB))
        h_int = sum(wi * h for wi, h in zip(w, half))
        i = int(np.argmin(np.linalg.norm(corners - tv, axis=1)))
        rx = results[i].fit.expand(v)
        model = np.concatenate([rx.A, rx.B], axis=1)
        std = np.concatenate([rx.std_A, rx.std_B], axis=1)
        need = np.abs(model - interp) + q * std - h_int
        if worst_at is None or need.max() > pad.max():
            worst_at = [float(x) for x in v]
        pad = np.maximum(pad, need)
    n = AB[0].shape[0]
    return {
        "pad_A": pad[:, :n].tolist(),
        "pad_B": pad[:, n:].tolist(),
        "points": len(GRID_T),
        "elements_padded": int(np.count_nonzero(pad)),
        "max_pad": float(pad.max()),
        "worst_point": worst_at,
        "quantile": q,
        "method": "nearest vertex's identified model re-expanded at 27 grid points (centre, "
        "faces, edges, half-way points) +/- q std there, minus the interpolated half-width "
        "(ident/vertex/interpolation.py); measured on the grid, not proven between its points",
    }
