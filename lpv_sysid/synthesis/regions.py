"""LMI-region pole placement for polytopic LPV systems (seed 2 Secs. 5.2-5.5, Eqs. 113-131).

An LMI region D = {z : f_D(z) = alpha + z beta + conj(z) beta^T < 0} (Eq. 113-114) is stored by
its characteristic matrices (alpha, beta). Supported building blocks (any intersection of them,
block-diagonal stacking of the characteristic functions):

* disk with centre ``(-q, 0)`` and radius ``r`` (Eq. 117):  alpha = [[-r, q], [q, -r]],
  beta = [[0, 1], [0, 0]];
* vertical strip ``S_min < Re z < S_max`` (Eq. 119): alpha = diag(S_min, -S_max),
  beta = diag(-1/2, 1/2); a half-plane ``Re z < -a`` is the strip with only its right edge.

The region is a subset of the complex plane, so continuous and discrete time use the same
LMIs; only the meaning differs (``Region.stable_for(time)`` checks that D lies in the open
left half-plane, resp. in the open unit disk).

State feedback (Eqs. 125-127): one common X = X^T > 0 and Gamma_i per scheduling vertex with
M_D(A_i^j X + B_i^j Gamma_i, X) = alpha (x) X + beta (x) (A X + B Gamma) + beta^T (x) (A X + B
Gamma)^T < 0
for all vertices i and uncertainty vertices j; K_i = Gamma_i X^-1 (quadratic D-stability of the
polytope with the law of Eq. 124). Observer (Sec. 5.5, Eqs. 130-131): by duality the gain L_i^T is
a state feedback for (A_i^T, C^T); the error e = x_hat - x obeys e' = (A_i + L_i C) e.
Integral augmentation (Eqs. 128-129) builds [[A, 0], [C, I]] (discrete) or [[A, 0], [C, 0]]
(continuous, x_I' = C x - r).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError, SolverError


@dataclass(frozen=True)
class DiskSpec:
    """``disk`` of a region file entry: centre ``(centre, 0)`` (``center`` is accepted too)
    and radius, seed 2 Eq. (117)."""

    centre: float = cf.number(doc="centre on the real axis (= -q)")
    radius: float = cf.number(doc="radius r > 0", lo=0.0, lo_open=True)

    @classmethod
    def from_dict(cls, d: Any, where: str = "region.disk") -> "DiskSpec":
        if isinstance(d, Mapping) and "center" in d:  # the US spelling of the key
            d = {("centre" if k == "center" else k): v for k, v in d.items() if k != "centre"}
        return cls(**cf.parse_fields(cls, d, where))


@dataclass(frozen=True)
class StripSpec:
    """``strip`` of a region file entry: ``min < Re z < max`` (Eq. 119; ``max`` null: the
    half-plane ``Re z > min``)."""

    min: float = cf.number(doc="S_min, the left edge")
    max: Optional[float] = cf.number(None, "S_max, the right edge (null: none)", optional=True)

    @classmethod
    def from_dict(cls, d: Any, where: str = "region.strip") -> "StripSpec":
        return cls(**cf.parse_fields(cls, d, where))


@dataclass(frozen=True)
class HalfPlaneSpec:
    """``half_plane`` of a region file entry: ``Re z < -alpha`` (Eq. 119, right edge only)."""

    alpha: float = cf.number(doc="the half-plane Re z < -alpha")

    @classmethod
    def from_dict(cls, d: Any, where: str = "region.half_plane") -> "HalfPlaneSpec":
        return cls(**cf.parse_fields(cls, d, where))


#: the keys of a region file entry -> their declared sections
_REGION_SECTIONS: dict[str, Any] = {
    "disk": DiskSpec,
    "strip": StripSpec,
    "half_plane": HalfPlaneSpec,
}


@dataclass(frozen=True)
class Region:
    """Intersection of a disk and a vertical strip (either may be absent). The file form
    (:meth:`from_dict`, :meth:`to_dict`) is ``{disk: {centre, radius}, strip: {min, max},
    half_plane: {alpha}}``, each section declared once (:class:`DiskSpec`,
    :class:`StripSpec`, :class:`HalfPlaneSpec`)."""

    disk_q: Optional[float] = None  # disk centre is (-q, 0) (seed 2 Eq. 117)
    disk_r: Optional[float] = None
    s_min: Optional[float] = None  # strip S_min < Re z < S_max (Eq. 119)
    s_max: Optional[float] = None

    @classmethod
    def from_dict(cls, d: Optional[dict], where: str = "region") -> Optional["Region"]:
        """The region of a file entry (None for an empty one); a half-plane and a strip
        together keep the smaller right edge."""
        if not d:
            return None
        cf.check_keys(d, _REGION_SECTIONS, where, list_allowed=True)
        parts = {
            k: spec.from_dict(d[k], cf.join(where, k))
            for k, spec in _REGION_SECTIONS.items()
            if k in d
        }
        kw: dict = {}
        if "disk" in parts:
            kw["disk_q"], kw["disk_r"] = -parts["disk"].centre, parts["disk"].radius
        if "strip" in parts:
            kw["s_min"], kw["s_max"] = parts["strip"].min, parts["strip"].max
        if "half_plane" in parts:
            edge = -parts["half_plane"].alpha
            kw["s_max"] = edge if kw.get("s_max") is None else min(kw["s_max"], edge)
        reg = cls(**kw)
        reg.check()
        return reg

    @property
    def disk(self) -> Optional[tuple[float, float]]:
        """(q, r) of the disk (centre (-q, 0), radius r; Eq. 117), None without one."""
        if self.disk_q is None or self.disk_r is None:
            return None
        return self.disk_q, self.disk_r

    def to_dict(self) -> dict:
        out: dict = {}
        if self.disk is not None:
            q, r = self.disk
            out["disk"] = {"centre": -float(q), "radius": float(r)}
        if self.s_min is not None:
            out["strip"] = {
                "min": float(self.s_min),
                "max": None if self.s_max is None else float(self.s_max),
            }
        elif self.s_max is not None:
            out["half_plane"] = {"alpha": -float(self.s_max)}
        return out

    def check(self) -> None:
        if (self.disk_q is None) != (self.disk_r is None):
            raise ConfigError("region: a disk needs both centre and radius")
        if self.disk_r is not None and not self.disk_r > 0:
            raise ConfigError(f"region: disk radius must be > 0, got {self.disk_r}")
        if self.s_min is not None and self.s_max is not None and not self.s_min < self.s_max:
            raise ConfigError(f"region: strip needs min < max, got [{self.s_min}, {self.s_max}]")

    def characteristic(self) -> tuple[np.ndarray, np.ndarray]:
        """(alpha, beta) of Eq. (114), block-diagonal over the components."""
        blocks: list[tuple[np.ndarray, np.ndarray]] = []
        if self.disk_r is not None:
            blocks.append(
                (
                    np.array([[-self.disk_r, self.disk_q], [self.disk_q, -self.disk_r]]),
                    np.array([[0.0, 1.0], [0.0, 0.0]]),
                )
            )
        if self.s_min is not None:
            blocks.append((np.array([[self.s_min]]), np.array([[-0.5]])))
        if self.s_max is not None and np.isfinite(self.s_max):
            blocks.append((np.array([[-self.s_max]]), np.array([[0.5]])))
        if not blocks:
            raise ConfigError("region: empty (give a disk, a strip or a half-plane)")
        m = sum(b[0].shape[0] for b in blocks)
        alpha = np.zeros((m, m))
        beta = np.zeros((m, m))
        k = 0
        for a, b in blocks:
            d = a.shape[0]
            alpha[k : k + d, k : k + d] = a
            beta[k : k + d, k : k + d] = b
            k += d
        return alpha, beta

    def contains(self, z: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """Elementwise membership of the (open) region, with a tolerance margin ``tol`` >= 0."""
        z = np.asarray(z, dtype=complex)
        ok = np.ones(z.shape, dtype=bool)
        if self.disk_r is not None:
            ok &= np.abs(z + self.disk_q) < self.disk_r + tol
        if self.s_min is not None:
            ok &= z.real > self.s_min - tol
        if self.s_max is not None:
            ok &= z.real < self.s_max + tol
        return ok

    def stable_for(self, ts: Optional[float]) -> bool:
        """True when D lies in the stability region (LHP for ts None, unit disk otherwise)."""
        if ts is None:
            if self.s_max is not None and self.s_max <= 0:
                return True
            return self.disk is not None and -self.disk[0] + self.disk[1] <= 0
        if self.disk is not None and abs(self.disk[0]) + self.disk[1] <= 1:
            return True
        return False


def region_lmi(alpha: np.ndarray, beta: np.ndarray, X, AX):
    """cvxpy expression M_D = alpha (x) X + beta (x) AX + beta^T (x) AX^T (seed 2 Eq. 115)."""
    import cvxpy as cp

    return cp.kron(alpha, X) + cp.kron(beta, AX) + cp.kron(beta.T, AX.T)


@dataclass
class PlacementResult:
    K: np.ndarray  # (N, m, n) vertex gains, K_i = Gamma_i X^-1
    X: np.ndarray  # common Lyapunov matrix
    status: str
    solver: str
    solve_time: float


def place_poles(
    systems: Sequence[Sequence[tuple[np.ndarray, np.ndarray]]],
    region: Region,
    eps: float = 1e-6,
    solver: str = "CLARABEL",
) -> PlacementResult:
    """Quadratic D-stabilisation of a nested polytope, seed 2 Eqs. (125)-(127).

    ``systems[i]`` is the list of (A_i^j, B_i^j); one Gamma_i per scheduling vertex i, one X.
    """
    import cvxpy as cp

    region.check()
    alpha, beta = region.characteristic()
    A0, B0 = systems[0][0]
    n, m = np.shape(B0)
    X = cp.Variable((n, n), symmetric=True)
    G = [cp.Variable((m, n)) for _ in systems]
    cons = [X >> eps * np.eye(n)]
    d = alpha.shape[0] * n
    for i, lst in enumerate(systems):
        for A, B in lst:
            AX = np.asarray(A) @ X + np.asarray(B) @ G[i]
            M = region_lmi(alpha, beta, X, AX)
            cons.append(0.5 * (M + M.T) << -eps * np.eye(d))
    prob = cp.Problem(cp.Minimize(0), cons)
    try:
        prob.solve(solver=solver)
    except cp.error.SolverError as exc:
        raise SolverError(
            f"pole placement LMI (seed 2 Eq. 125): solver {solver} failed: {exc}"
        ) from None
    if prob.status not in ("optimal", "optimal_inaccurate"):
        raise SolverError(
            f"pole placement LMI (seed 2 Eq. 125): {prob.status}; the polytope is not "
            f"quadratically D-stabilisable for region {region.to_dict()}"
        )
    Xv = np.asarray(X.value)
    K = np.array([np.linalg.solve(Xv.T, np.asarray(g.value).T).T for g in G])
    return PlacementResult(
        K=K,
        X=Xv,
        status=prob.status,
        solver=solver,
        solve_time=float(prob.solver_stats.solve_time or np.nan),
    )


def place_observer(
    systems: Sequence[Sequence[tuple[np.ndarray, np.ndarray]]],
    C: np.ndarray,
    region: Region,
    eps: float = 1e-6,
    solver: str = "CLARABEL",
) -> tuple[np.ndarray, PlacementResult]:
    """LPV observer gains L_i (seed 2 Sec. 5.5, Eqs. 130-131) with eig(A_i^j + L_i C) in D.

    Duality: L_i^T is the state-feedback gain of (A_i^j^T, C^T). Returns (L (N, n, p), dual
    result).
    """
    C = np.asarray(C, dtype=float)
    dual = [[(np.asarray(A).T, C.T) for A, _B in lst] for lst in systems]
    res = place_poles(dual, region, eps, solver)
    return np.transpose(res.K, (0, 2, 1)), res


def integral_augmentation(
    A: np.ndarray, B: np.ndarray, C: np.ndarray, ts: Optional[float] = None
) -> tuple[np.ndarray, np.ndarray]:
    """Augmented (A, B) of seed 2 Eq. (129) with x_I the integral of e = C x - r.

    Discrete time (ts given): x_I(k+1) = x_I(k) + C x(k) - r(k) (Eq. 128) -> [[A, 0], [C, I]].
    Continuous time: x_I' = C x - r -> [[A, 0], [C, 0]]. The reference enters through -[0; I].
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    C = np.asarray(C, dtype=float)
    p = C.shape[0]
    n = A.shape[0]
    lower_right = np.eye(p) if ts is not None else np.zeros((p, p))
    Aa = np.block([[A, np.zeros((n, p))], [C, lower_right]])
    Ba = np.vstack([B, np.zeros((p, B.shape[1]))])
    return Aa, Ba


def closed_loop_eigs(systems, K: np.ndarray) -> list[np.ndarray]:
    """eig(A_i^j + B_i^j K_i) for every (i, j) (flat list)."""
    out = []
    for i, lst in enumerate(systems):
        for A, B in lst:
            out.append(np.linalg.eigvals(np.asarray(A) + np.asarray(B) @ K[i]))
    return out
