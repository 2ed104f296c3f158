"""Bounding-box polytope of the TRMS quasi-LPV model (seed 2 Secs. 3.4-3.5, 6.2-6.3, Eqs.
59-65): the p box of Table 7, psi bounds, Euler discretisation and the vertex matrices."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.trms.model import Trms
from lpv_sysid.models.trms.params import (
    P_NAMES,
    PSI_NAMES,
    REDUCED_PSI,
    TABLE7_RANGES,
    TS_PAPER,
    TrmsParams,
)

# --------------------------------------------------------------------------- bounding box, Sec.
# 3.4-3.5
#: which p variables each psi_j depends on (indices into P_NAMES); used to grid only those.
PSI_DEPENDS = ((2,), (1, 2), (1,), (0, 1), (1, 3), (1, 3), (1,), (3,), (1, 3, 4), (3,), (1,))


def p_box(
    params: TrmsParams, ranges: Optional[Mapping[str, tuple]] = None
) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of p = (theta_h, theta_v, omega_h, omega_v, Omega_h) from Table 7 (theta_v
    absolute)."""
    r = dict(TABLE7_RANGES)
    r.update(ranges or {})
    tv0 = params.theta_v0
    lo = np.array(
        [
            r["theta_h"][0],
            r["dtheta_v"][0] + tv0,
            r["omega_h"][0],
            r["omega_v"][0],
            r["Omega_h"][0],
        ]
    )
    hi = np.array(
        [
            r["theta_h"][1],
            r["dtheta_v"][1] + tv0,
            r["omega_h"][1],
            r["omega_v"][1],
            r["Omega_h"][1],
        ]
    )
    if np.any(hi <= lo):
        raise ConfigError(f"trms p box: need max > min, got {lo.tolist()} / {hi.tolist()}")
    return lo, hi


def psi_bounds(
    model: Trms,
    plo,
    phi,
    n_grid: int = 201,
    gaps: Optional[Mapping[str, tuple]] = None,
    max_points: int = 200_000,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounding box of psi over the p box (Eq. 62): (min (11,), max (11,), least-squares constant
    (11,)).

    Seed 2 Sec. 3.5 takes the extremes "by numerical optimization"; here each psi_j is gridded
    over only the p variables it depends on (PSI_DEPENDS, <= 3 of them; at most ``max_points``
    points per psi), with the box edges, 0 and the sign switches of Eqs. (15)-(20) added to the
    grid. ``gaps`` = {name: (minus, plus)} removes the open interval (minus, plus) of a p variable
    (Eq. 69; names of P_NAMES, theta_v given as the offset from theta_v^0) and adds its edges.
    The third output is the grid mean, the least-squares constant used for frozen parameters (Sec.
    6.3).
    """
    plo = np.asarray(plo, dtype=float)
    phi = np.asarray(phi, dtype=float)
    gaps = dict(gaps or {})
    bad = sorted(set(gaps) - set(P_NAMES))
    if bad:
        raise ConfigError(f"trms gaps: unknown variable(s) {bad}; known: {list(P_NAMES)}")
    mid = 0.5 * (plo + phi)
    lo = np.empty(11)
    hi = np.empty(11)
    mean = np.empty(11)
    for j, dep in enumerate(PSI_DEPENDS):
        per_axis = max(11, min(n_grid, int(max_points ** (1.0 / len(dep)))))
        axes = []
        for k in dep:
            g = np.linspace(plo[k], phi[k], per_axis)
            extra = [0.0, model.p.theta_v0] if k == 1 else [0.0]
            if P_NAMES[k] in gaps:
                off = model.p.theta_v0 if k == 1 else 0.0
                gm, gp = (float(v) + off for v in gaps[P_NAMES[k]])
                g = g[(g <= gm) | (g >= gp)]
                extra = [e for e in extra if not gm < e < gp] + [gm, gp]
            extra = [e for e in extra if plo[k] <= e <= phi[k]]
            axes.append(np.unique(np.concatenate([g, extra])))
        grids = np.meshgrid(*axes, indexing="ij")
        P = np.broadcast_to(mid, grids[0].shape + (5,)).copy()
        for k, gk in zip(dep, grids):
            P[..., k] = gk
        v = model.psi(P)[..., j]
        lo[j], hi[j], mean[j] = v.min(), v.max(), v.mean()
    return lo, hi, mean


def euler_discrete(A: np.ndarray, B: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray]:
    """A_d = I + Ts A, B_d = Ts B (Euler, Eqs. 59-61)."""
    n = A.shape[-1]
    return np.eye(n) + ts * A, ts * B


@dataclass
class TrmsPolytope:
    """Bounding-box polytope of the (reduced) scheduling vector, Eqs. (62)-(65), discrete or
    continuous.

    ``names`` the scheduled psi (a subset of PSI_NAMES), ``lo``/``hi`` their box, ``frozen`` the
    constants used for the other psi and for b22 (Sec. 6.3 and footnote 1), ``A`` (2**q, 6, 6) the
    vertex matrices in the order of :func:`lpv_sysid.models.lpv.box_vertices` (first psi slowest),
    ``B`` the common input matrix, ``ts`` None (continuous) or the Euler sample time.
    """

    model: Trms
    names: tuple
    lo: np.ndarray
    hi: np.ndarray
    frozen: dict
    A: np.ndarray
    B: np.ndarray
    ts: Optional[float]

    @property
    def index(self) -> list[int]:
        return [PSI_NAMES.index(n) for n in self.names]

    def psi_full(self, x) -> np.ndarray:
        """All 11 psi at state x with the frozen ones replaced by their constants."""
        v = self.model.psi(self.model.p_of_x(x))
        for k, name in enumerate(PSI_NAMES):
            if name in self.frozen:
                v[..., k] = self.frozen[name]
        return v

    def scheduled(self, x) -> np.ndarray:
        """The scheduled psi at x (for the multilinear weights)."""
        return self.model.psi(self.model.p_of_x(x))[..., self.index]

    def weights(self, x) -> tuple[np.ndarray, bool]:
        """pi_i(psi(x)) of Eq. (65) (multilinear, seed 0 Eq. 21); True when psi left the box."""
        from lpv_sysid.models.lpv import multilinear_weights

        return multilinear_weights(self.scheduled(x), self.lo, self.hi)

    def A_at(self, x) -> np.ndarray:
        """sum_i pi_i A_i; equals the reduced A(psi(x)) (Euler-discretised if ts) inside the
        box."""
        alpha, _ = self.weights(x)
        return np.tensordot(alpha, self.A, axes=1)

    def contains(self, x, tol: float = 1e-12) -> bool:
        v = self.scheduled(x)
        return bool(np.all(v >= self.lo - tol) and np.all(v <= self.hi + tol))


def bounding_box_polytope(
    model: Trms,
    names: Sequence[str] = REDUCED_PSI,
    ts: Optional[float] = TS_PAPER,
    ranges: Optional[Mapping[str, tuple]] = None,
    gaps: Optional[Mapping[str, tuple]] = None,
    n_grid: int = 201,
) -> TrmsPolytope:
    """Polytopic quasi-LPV model of Sec. 3.5 / 6.2 (bounding box over Table 7), vertices per Eq.
    (65).

    psi not in ``names`` are frozen at their least-squares constant over the box (Sec. 6.3), and so
    is b22 (footnote 1 of Eq. 41). With ``ts`` the vertices are the Euler A_d of Eq. (60).
    """
    from lpv_sysid.models.lpv import box_vertices

    bad = [n for n in names if n not in PSI_NAMES]
    if bad or len(set(names)) != len(names) or not names:
        raise ConfigError(
            f"trms polytope: scheduled parameters must be distinct names from {PSI_NAMES}, got "
            f"{list(names)}"
        )
    plo, phi = p_box(model.p, ranges)
    lo, hi, mean = psi_bounds(model, plo, phi, n_grid, gaps)
    idx = [PSI_NAMES.index(n) for n in names]
    frozen = {PSI_NAMES[k]: float(mean[k]) for k in range(11) if k not in idx}
    tv = np.linspace(plo[1], phi[1], n_grid)
    frozen["b22"] = float(np.mean(model.b22(tv)))
    base = mean.copy()
    verts = box_vertices(lo[idx], hi[idx])
    vertex_A = []
    for v in verts:
        psi = base.copy()
        psi[idx] = v
        vertex_A.append(model.A_of_psi(psi))
    A = np.array(vertex_A)
    B = model.B_of(model.p.theta_v0)
    B[1, 1] = frozen["b22"]
    if ts is not None:
        A, B = euler_discrete(A, B, ts)
    return TrmsPolytope(
        model=model, names=tuple(names), lo=lo[idx], hi=hi[idx], frozen=frozen, A=A, B=B, ts=ts
    )
