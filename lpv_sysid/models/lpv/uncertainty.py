"""Uncertainty vertices of seed 0 Eqs. (22), (23) and the common input set of Lemma 1.

Nested uncertainty vertices Lambda_i^j (seed 0 Eq. 23) are built per scheduling vertex from the
nominal ``(A_i, B_i)`` and the interval box of the uncertain elements (Eq. 22) by corner
enumeration, or taken from an explicit list (e.g. produced by
``lpv_sysid.ident.vertex.uncertainty``).

Common input matrix (why, and what it costs). Lemma 1 (seed 0 Sec. VI, Rotondo Thm. 2) certifies
the *whole* scheduling box only because the seed's input matrix depends on theta alone (Eq. 16):
B_c^j carries no vertex index. Identification estimates the B elements at every vertex, so
B_i^j differs between vertices; then sum_i alpha_i sum_j beta_i^j B_i^j S_i contains the cross
terms alpha_i alpha_k B_i S_k and is *not* B(v_d) S(v_d): the LMIs hold at the vertices, the
interior is uncovered (B(v_d) K(v_d) is bilinear in alpha). :func:`input_hull` closes the hole
conservatively: every B element that is uncertain or differs across vertices gets the interval
hull over all vertices of [lower_i, upper_i] and of the nominal values B_i (so it contains
B(v_d, theta) = sum_i alpha_i B_i(theta_i) for every v_d in the box and theta in Eq. 22); its
corners B^b, b = 1..M_B, are enumerated once and combined as a product with each vertex's
A-corners A_i^a (:func:`product_systems`): Lambda_i^(a,b) = (A_i^a, B^b, B^b R, C), M_i = M_A,i
M_B.
With product weights beta_i^(a,b) = beta_i^a beta^b (beta_i^a the A-weights of vertex i, beta^b
the B-weights, both summing to 1) the B part's weight is independent of i:
sum_a beta_i^a beta^b = beta^b. Summing Eq. (30) with the non-negative weights
alpha_i beta_i^a beta^b (sum 1) gives, because Eq. (30) is affine in (A, B_c, B_e, X) for fixed
(S_i, H) and U = A H + B_c S_i,

    sum_i alpha_i sum_(a,b) beta_i^a beta^b U_i^(a,b)
        = A(v_d, theta) H + (sum_b beta^b B^b)(sum_i alpha_i S_i) = A(v_d, theta) H + B(theta)
        S(v_d),

i.e. Eq. (30) for the frozen system (A(v_d, theta), B(theta)) with X(v_d, theta) =
sum alpha_i beta_i^a beta^b X_i^(a,b) > 0 and the gain S(v_d) H^-1 = sum_i alpha_i K_i = K(v_d)
(Eq. 31): B(theta) K(v_d) = sum_i alpha_i sum_b beta^b B^b S_i H^-1. So ||u_e -> z||_inf < gamma at
every frozen v_d in the box, which is what Lemma 1 claims (a parameter-dependent X certifies frozen
points; rate bounds are outside the seed's lemma). The price is conservatism (the B hull ignores
the correlation of B with v_d) and size: M_i = M_A M_B.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace
from typing import Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError

#: corner enumeration of p uncertain elements gives 2**p systems; refuse more than this.
MAX_CORNERS_DEFAULT = 4096


# --------------------------------------------------------------------------- uncertainty
@dataclass(frozen=True)
class UncertainElement:
    """One identified matrix element with its interval (seed 0 Eq. 22)."""

    matrix: str  # "A" or "B"
    row: int
    col: int
    lower: float
    upper: float
    nominal: Optional[float] = None

    @classmethod
    def from_dict(cls, d: dict) -> "UncertainElement":
        try:
            el = cls(
                matrix=str(d["matrix"]),
                row=int(d["row"]),
                col=int(d["col"]),
                lower=float(d["lower"]),
                upper=float(d["upper"]),
                nominal=None if d.get("nominal") is None else float(d["nominal"]),
            )
        except KeyError as exc:
            raise ConfigError(f"uncertain element {d!r}: missing key {exc}") from None
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"uncertain element {d!r}: {exc}") from None
        if el.matrix not in ("A", "B"):
            raise ConfigError(f"uncertain element: 'matrix' must be 'A' or 'B', got {el.matrix!r}")
        if not (np.isfinite(el.lower) and np.isfinite(el.upper)) or el.upper < el.lower:
            raise ConfigError(
                f"uncertain element {el.matrix}[{el.row},{el.col}]: need finite lower <= upper, "
                f"got [{el.lower}, {el.upper}]"
            )
        return el


def uncertainty_vertices(
    A: np.ndarray,
    B: np.ndarray,
    elements: Sequence[UncertainElement],
    max_corners: int = MAX_CORNERS_DEFAULT,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Lambda_i^j of seed 0 Eq. (23): all 2**p corners of the interval box of the elements.

    Corner order: itertools.product over (lower, upper) per element, first element slowest.
    Elements with lower == upper are fixed (they do not double the count). With no uncertain
    elements the single nominal system is returned.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    free = []
    for el in elements:
        mat = A if el.matrix == "A" else B
        if not (0 <= el.row < mat.shape[0] and 0 <= el.col < mat.shape[1]):
            raise ConfigError(
                f"uncertain element {el.matrix}[{el.row},{el.col}] outside shape {mat.shape}"
            )
        if el.upper > el.lower:
            free.append(el)
    n_corners = 2 ** len(free)
    if n_corners > max_corners:
        raise ConfigError(
            f"{len(free)} uncertain elements give {n_corners} corners (> "
            f"max_corners={max_corners}); "
            "pass an explicit list of vertex systems (ident.uncertainty) or raise max_corners"
        )
    base_A, base_B = A.copy(), B.copy()
    for el in elements:
        if el.upper == el.lower:
            (base_A if el.matrix == "A" else base_B)[el.row, el.col] = el.lower
    out = []
    for corner in itertools.product(*[(el.lower, el.upper) for el in free]):
        Aj, Bj = base_A.copy(), base_B.copy()
        for el, val in zip(free, corner):
            (Aj if el.matrix == "A" else Bj)[el.row, el.col] = val
        out.append((Aj, Bj))
    return out


# --------------------------------------------------------------------------- common input set
@dataclass(frozen=True)
class CommonInputSet:
    """Input-matrix corners B^b (b = 1..M_B) shared by all scheduling vertices (module docstring).

    ``corners`` (M_B, n, m); ``elements`` the hull intervals of :func:`input_hull` (``nominal`` =
    mean of the vertex nominals); ``nominal_lo``/``nominal_hi`` (n, m) the elementwise min/max of
    the vertex nominal B_i (the set that remains when the identified intervals shrink to zero);
    ``method`` how the corners were generated (``box`` = all corners of the hull, else the
    reduction of :mod:`lpv_sysid.ident.vertex.uncertainty`).
    """

    corners: np.ndarray
    elements: tuple = ()
    nominal_lo: Optional[np.ndarray] = None
    nominal_hi: Optional[np.ndarray] = None
    method: str = "box"

    @property
    def M(self) -> int:
        return int(np.shape(self.corners)[0])

    def shrunk(self, rho: float) -> "CommonInputSet":
        """Corners with the identified interval widths scaled by rho about the nominal hull
        (remedy 3 of seed 0 Sec. VI): B^b -> c^b + rho (B^b - c^b), c^b = B^b clipped into
        [nominal_lo, nominal_hi]. For box corners the result is the hull box
        [(1 - rho) min_i B_i + rho min_i lower_i, ...], which contains the hull of the per-vertex
        shrunk intervals [(1 - rho) B_i + rho lower_i, ...] (min of a sum >= sum of mins), with
        equality when one vertex attains both minima (and both maxima)."""
        corners = np.asarray(self.corners, dtype=float)
        lo = corners.min(axis=0) if self.nominal_lo is None else self.nominal_lo
        hi = corners.max(axis=0) if self.nominal_hi is None else self.nominal_hi
        c = np.clip(corners, lo, hi)
        return replace(self, corners=c + rho * (corners - c))


def input_hull(
    B: np.ndarray, elements: Sequence[Sequence[UncertainElement]]
) -> tuple[np.ndarray, list[UncertainElement], np.ndarray, np.ndarray]:
    """Interval hull over all scheduling vertices of the input matrix (module docstring).

    ``B`` (N, n, m) nominal vertex input matrices, ``elements[i]`` the uncertain elements of vertex
    i (the B ones are used). For every B element that has a non-degenerate interval at some vertex
    or whose nominal value differs between vertices, the hull is
    ``[min_i min(lower_i, B_i), max_i max(upper_i, B_i)]`` (a vertex without an interval for that
    element contributes its nominal value). Returns (base B (n, m) -- identical-across-vertices
    elements as they are, hull elements at their mean nominal --, hull elements in row-major
    order, nominal_lo, nominal_hi).
    """
    B = np.asarray(B, dtype=float)
    if B.ndim != 3 or len(elements) != B.shape[0]:
        raise ConfigError(
            f"input_hull: need B (N, n, m) and one element list per vertex, got {B.shape} "
            f"and {len(elements)} lists"
        )
    lo = B.min(axis=0)
    hi = B.max(axis=0)
    nom_lo, nom_hi = lo.copy(), hi.copy()
    for i, els in enumerate(elements):
        for el in els:
            if el.matrix != "B":
                continue
            if not (0 <= el.row < B.shape[1] and 0 <= el.col < B.shape[2]):
                raise ConfigError(
                    f"uncertain element B[{el.row},{el.col}] outside shape {B.shape[1:]} "
                    f"(vertex {i})"
                )
            lo[el.row, el.col] = min(lo[el.row, el.col], el.lower)
            hi[el.row, el.col] = max(hi[el.row, el.col], el.upper)
    base = B[0].copy()
    mean = B.mean(axis=0)
    hull = []
    for r, c in zip(*np.nonzero(hi > lo)):
        base[r, c] = mean[r, c]
        hull.append(
            UncertainElement(
                "B", int(r), int(c), float(lo[r, c]), float(hi[r, c]), float(mean[r, c])
            )
        )
    return base, hull, nom_lo, nom_hi


def input_corners(
    base_B: np.ndarray, hull: Sequence[UncertainElement], max_corners: int = MAX_CORNERS_DEFAULT
) -> np.ndarray:
    """All 2**p corners B^b of the hull box (order of :func:`uncertainty_vertices`),
    shape (M_B, n, m)."""
    base_B = np.asarray(base_B, dtype=float)
    n = base_B.shape[0]
    return np.array(
        [b for _, b in uncertainty_vertices(np.zeros((n, n)), base_B, hull, max_corners)]
    )


def product_systems(a_corners: Sequence[Sequence[np.ndarray]], common: CommonInputSet) -> list:
    """Lambda_i^(a,b) = (A_i^a, B^b), flattened as j = a * M_B + b (A slowest), module
    docstring."""
    return [
        [
            (np.asarray(Aa, dtype=float), np.asarray(Bb, dtype=float))
            for Aa in lst
            for Bb in common.corners
        ]
        for lst in a_corners
    ]
