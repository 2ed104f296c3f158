"""The element box in the scaled coordinates of the robust LMI
(:mod:`lpv_sysid.synthesis.robust`): :class:`ScaledBox`, the scaling chosen on the box
bounds, the per-vertex element maps of the compressed block and the edge pairs of the
``rate`` form."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lpv_sysid.models.lpv import ElementBox, box_vertices
from lpv_sysid.synthesis.scaling import Scaling, choose_scaling


@dataclass
class ScaledBox:
    """The element box and the LMI data in the scaled coordinates of :mod:`scaling`."""

    A: list  # per vertex A_c~ (n, n)
    B: np.ndarray  # B_c~ (n, m)
    Be: np.ndarray  # B_c~ R~ = T^-1 B_c R (n, n_e)
    Rs: np.ndarray  # R in the scaled input coordinates, S_u^-1 R (m, n_e)
    C: np.ndarray  # C T (n_z, n)
    rows: list
    cols: list
    half: list  # scaled half-widths h_l tau_c / t_r
    used: list  # columns of [x; u] that carry elements (sorted, union over the vertices)
    tau: np.ndarray  # [t; s_u]


def scale_box(box: ElementBox, R: np.ndarray, C: np.ndarray, scaling: Scaling) -> ScaledBox:
    tau = np.r_[scaling.t, scaling.s_u]
    A = [scaling.A(np.asarray(a, dtype=float)) for a in box.A_centre]
    B = scaling.Bc(np.asarray(box.B_centre, dtype=float))
    rows, cols, half = [], [], []
    for i in range(box.N):
        r, c, h = box.arrays(i)
        rows.append(r)
        cols.append(c)
        half.append(h * tau[c] / scaling.t[r])
    used = sorted({int(c) for cc in cols for c in cc})
    Rs = np.asarray(R, dtype=float) / scaling.s_u[:, None]
    return ScaledBox(
        A,
        B,
        scaling.Be(np.asarray(box.B_centre, dtype=float) @ R),
        Rs,
        scaling.C(C),
        rows,
        cols,
        half,
        used,
        tau,
    )


def box_scaling(box: ElementBox, R: np.ndarray, C: np.ndarray) -> Scaling:
    """:func:`choose_scaling` on the box bounds (centre and both ends of every element)."""
    As, Bs = [], []
    for i in range(box.N):
        lo, hi = box.bounds(i)
        for AB in (lo, hi):
            As.append(np.abs(AB[:, : box.n]))
            Bs.append(np.abs(AB[:, box.n :]))
    return choose_scaling(As, Bs, [b @ R for b in Bs], C)


def rate_vertex_pairs(vmin: np.ndarray, vmax: np.ndarray) -> list:
    """For every vertex i and axis k: (i_minus, i_plus, width_k), the vertices of the edge through
    i along k (box order of :func:`box_vertices`), so D_k X at i = (X_plus - X_minus) / width."""
    V = box_vertices(vmin, vmax)
    p = V.shape[1]
    out = []
    for i in range(V.shape[0]):
        per = []
        for k in range(p):
            lo_v, hi_v = V[i].copy(), V[i].copy()
            lo_v[k], hi_v[k] = vmin[k], vmax[k]
            im = int(np.nonzero(np.all(V == lo_v, axis=1))[0][0])
            ip = int(np.nonzero(np.all(V == hi_v, axis=1))[0][0])
            per.append((im, ip, float(vmax[k] - vmin[k])))
        out.append(per)
    return out


def element_maps(sb: ScaledBox, i: int):
    """(Srow (n, p): h_l^2 at row r_l, Scol (n_c, p): 1 at the used-column index of c_l, colk)."""
    r, c, h = sb.rows[i], sb.cols[i], sb.half[i]
    n = sb.A[0].shape[0]
    p = r.size
    Srow = np.zeros((n, p))
    Srow[r, np.arange(p)] = h**2
    colk = np.array([sb.used.index(int(x)) for x in c], dtype=int)
    Scol = np.zeros((len(sb.used), p))
    Scol[colk, np.arange(p)] = 1.0
    return Srow, Scol, colk
