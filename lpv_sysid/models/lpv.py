"""Polytopic (uncertain) LPV model over the scheduling box of seed 0 Eqs. (20)-(23).

Vertex order (fixed, documented, identical to the ``vertices`` list of ``vertex_models.yaml``
and ``gains.yaml``): ``itertools.product(*[(min_k, max_k) for k in axes])``, first axis
slowest. For the quadrotor box ``v_d = (u_d, v_d, w_d)`` vertex 0 is (min, min, min),
vertex 1 is (min, min, max), ..., vertex 7 is (max, max, max).

Multilinear weights (seed 0 Eq. 21): with ``t_k = (v_k - min_k) / (max_k - min_k)`` and the
1-D barycentric pair ``(1 - t_k, t_k)``, ``alpha_i = prod_k w_k(bit_ik)``, where bit_ik = 0 for
min and 1 for max. They are non-negative, sum to 1, and reproduce every affine (indeed every
multilinear) function of ``v_d`` exactly from its vertex values. Outside the box ``v_d`` is
clamped to the box and a flag is returned (the caller raises the safety event).

Nested uncertainty vertices Lambda_i^j (seed 0 Eq. 23) are built per scheduling vertex from the
nominal ``(A_i, B_i)`` and the interval box of the uncertain elements (Eq. 22) by corner
enumeration, or taken from an explicit list (e.g. produced by ``lpv_sysid.ident.uncertainty``).

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

The full identified box as a structured perturbation (:class:`ElementBox`). Corner enumeration of
Eq. (23) is exponential in the number of uncertain elements (~50 per vertex for the quadrotor), so
the whole Eq. (22) box -- every identified element in its interval -- is written instead in the
linear-fractional (LFT) form of a structured, norm-bounded perturbation of the box centre:

    [A_i(delta), B(delta)] = [A_c,i, B_c] + sum_l delta_l h_l e_(r_l) e_(c_l)^T,   |delta_l| <= 1,

one scalar delta_l per element l of vertex i (row r_l, column c_l of [A, B], half-width h_l). The
B elements are the common input hull of :func:`input_hull` (same argument as above: B carries no
vertex index, so the interior of the scheduling box is covered). The multipliers that turn this
into a finite LMI are in :mod:`lpv_sysid.synthesis.robust_lmi`. Corner polytopes of single-element
boxes (the influence / box reductions of :mod:`lpv_sysid.ident.uncertainty`) have the same form
(:func:`corner_box`), which is how the seed-size problem is solved with one block per vertex.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field, replace
from typing import Iterable, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from lpv_sysid.errors import ConfigError

log = logging.getLogger(__name__)

#: corner enumeration of p uncertain elements gives 2**p systems; refuse more than this.
MAX_CORNERS_DEFAULT = 4096


# --------------------------------------------------------------------------- box and weights
def box_vertices(vmin: ArrayLike, vmax: ArrayLike) -> np.ndarray:
    """Corners of the box [vmin, vmax] (seed 0 Eq. 20), shape (2**p, p), first axis slowest."""
    lo, hi = _check_box(vmin, vmax)
    return np.array(list(itertools.product(*zip(lo, hi))), dtype=float)


def _check_box(vmin: ArrayLike, vmax: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(vmin, dtype=float).ravel()
    hi = np.asarray(vmax, dtype=float).ravel()
    if lo.shape != hi.shape or lo.size == 0:
        raise ConfigError(
            f"scheduling box: min {lo.shape} and max {hi.shape} must be equal, non-empty"
        )
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ConfigError("scheduling box: min/max must be finite")
    if np.any(hi <= lo):
        raise ConfigError(
            f"scheduling box: need max > min on every axis, got min={lo.tolist()} "
            f"max={hi.tolist()}"
        )
    return lo, hi


def multilinear_weights(v: ArrayLike, vmin: ArrayLike, vmax: ArrayLike) -> tuple[np.ndarray, bool]:
    """alpha_i(v) of seed 0 Eq. (21) for the vertex order of :func:`box_vertices`.

    Returns (alpha (2**p,), clamped). ``clamped`` is True when v was outside the box and was
    projected onto it before the weights were computed. NaN in ``v`` raises ConfigError.
    """
    lo, hi = _check_box(vmin, vmax)
    v = np.asarray(v, dtype=float).ravel()
    if v.shape != lo.shape:
        raise ConfigError(f"scheduling point has {v.size} entries, the box has {lo.size} axes")
    if not np.all(np.isfinite(v)):
        raise ConfigError(f"scheduling point contains NaN/inf: {v.tolist()}")
    t = (v - lo) / (hi - lo)
    clamped = bool(np.any(t < 0.0) or np.any(t > 1.0))
    t = np.clip(t, 0.0, 1.0)
    alpha = np.ones(1)
    for tk in t:
        alpha = np.kron(alpha, np.array([1.0 - tk, tk]))  # kron: first factor slowest
    return alpha, clamped


def multilinear_weight_gradient(v: ArrayLike, vmin: ArrayLike, vmax: ArrayLike) -> np.ndarray:
    """d alpha_i / d v_k, shape (2**p, p), at a point clamped into the box (used by Eq. 34).

    Outside the box the clamped coordinate has zero derivative (the clamped model is flat).
    """
    lo, hi = _check_box(vmin, vmax)
    v = np.asarray(v, dtype=float).ravel()
    if not np.all(np.isfinite(v)):
        raise ConfigError(f"scheduling point contains NaN/inf: {v.tolist()}")
    t_raw = (v - lo) / (hi - lo)
    t = np.clip(t_raw, 0.0, 1.0)
    inside = (t_raw >= 0.0) & (t_raw <= 1.0)
    p = lo.size
    grad = np.empty((2**p, p))
    for k in range(p):
        g = np.ones(1)
        for l_ in range(p):
            if l_ == k:
                d = np.array([-1.0, 1.0]) / (hi[k] - lo[k]) if inside[k] else np.zeros(2)
                g = np.kron(g, d)
            else:
                g = np.kron(g, np.array([1.0 - t[l_], t[l_]]))
        grad[:, k] = g
    return grad


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
    reduction of :mod:`lpv_sysid.ident.uncertainty`).
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


# --------------------------------------------------------------------------- element box (LFT)
@dataclass(frozen=True)
class ElementBox:
    """Every uncertain element of every vertex in its interval, as the structured perturbation of
    the module docstring: ``[A_i(delta), B(delta)] = [A_c[i], B_c] + sum_l delta_l h_l e_r e_c^T``.

    ``A_centre`` (N, n, n) and ``B_centre`` (n, m) are the interval midpoints (elements that are
    not uncertain keep the vertex value; B is common to all vertices). Per vertex i the elements
    are ``rows[i]``, ``cols[i]`` (column of [A, B]: ``c < n`` an A element, ``c >= n`` the B
    element (r, c - n)) and ``half[i]`` (> 0); the B elements are the same at every vertex (the
    common hull) and come after the A elements. ``labels[i]`` say where each interval came from.
    """

    A_centre: np.ndarray
    B_centre: np.ndarray
    rows: tuple
    cols: tuple
    half: tuple
    labels: tuple = ()

    def __post_init__(self) -> None:
        A = np.asarray(self.A_centre, dtype=float)
        B = np.asarray(self.B_centre, dtype=float)
        if A.ndim != 3 or A.shape[1] != A.shape[2] or B.ndim != 2 or B.shape[0] != A.shape[1]:
            raise ConfigError(f"element box: centre shapes A {A.shape}, B {B.shape}")
        n, m = B.shape
        if not (len(self.rows) == len(self.cols) == len(self.half) == A.shape[0]):
            raise ConfigError("element box: need rows, cols, half for every vertex")
        for i, (r, c, h) in enumerate(zip(self.rows, self.cols, self.half)):
            r, c, h = np.asarray(r), np.asarray(c), np.asarray(h, dtype=float)
            if not (r.shape == c.shape == h.shape) or r.ndim != 1:
                raise ConfigError(
                    f"element box: vertex {i}: rows/cols/half must be 1-D of one length"
                )
            if r.size and (r.min() < 0 or r.max() >= n or c.min() < 0 or c.max() >= n + m):
                raise ConfigError(
                    f"element box: vertex {i}: element outside [A, B] ({n} x {n + m})"
                )
            if not np.all(np.isfinite(h)) or np.any(h <= 0):
                raise ConfigError(f"element box: vertex {i}: half-widths must be finite and > 0")
            if len(set(zip(r.tolist(), c.tolist()))) != r.size:
                raise ConfigError(f"element box: vertex {i}: an element is listed twice")

    @property
    def N(self) -> int:
        return int(np.shape(self.A_centre)[0])

    @property
    def n(self) -> int:
        return int(np.shape(self.B_centre)[0])

    @property
    def m(self) -> int:
        return int(np.shape(self.B_centre)[1])

    @property
    def p(self) -> list:
        """Number of uncertain elements per vertex."""
        return [int(np.size(r)) for r in self.rows]

    def arrays(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return (
            np.asarray(self.rows[i], dtype=int),
            np.asarray(self.cols[i], dtype=int),
            np.asarray(self.half[i], dtype=float),
        )

    def system(self, i: int, delta: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(A_i(delta), B(delta)) for delta in [-1, 1]^p_i (module docstring)."""
        r, c, h = self.arrays(i)
        d = np.asarray(delta, dtype=float)
        if d.shape != h.shape:
            raise ConfigError(f"element box: vertex {i} has {h.size} elements, delta has {d.size}")
        AB = np.concatenate(
            [np.asarray(self.A_centre[i], dtype=float), np.asarray(self.B_centre, dtype=float)],
            axis=1,
        )
        np.add.at(AB, (r, c), d * h)
        return AB[:, : self.n].copy(), AB[:, self.n :].copy()

    def bounds(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Elementwise [lower, upper] of [A_i, B] over the box ((n, n + m) each)."""
        r, c, h = self.arrays(i)
        AB = np.concatenate(
            [np.asarray(self.A_centre[i], dtype=float), np.asarray(self.B_centre, dtype=float)],
            axis=1,
        )
        lo, hi = AB.copy(), AB.copy()
        np.add.at(lo, (r, c), -h)
        np.add.at(hi, (r, c), h)
        return lo, hi

    def sample_systems(self, nominal: Sequence[tuple], count: int = 16, seed: int = 0) -> list:
        """A finite subset of the box per vertex (the certified systems the flight runtime
        re-checks
        by eigenvalues): the centre, the given nominal (A_i, B_i) when it lies in the box, then
        corners delta in {-1, 1}^p drawn with a fixed seed (the same list every call)."""
        rng = np.random.default_rng(seed)
        out = []
        for i in range(self.N):
            lst = [self.system(i, np.zeros(self.p[i]))]
            lo, hi = self.bounds(i)
            A_i, B_i = (np.asarray(x, dtype=float) for x in nominal[i])
            AB = np.concatenate([A_i, B_i], axis=1)
            if np.all(AB >= lo - 1e-12 * (1 + np.abs(lo))) and np.all(
                AB <= hi + 1e-12 * (1 + np.abs(hi))
            ):
                lst.append((A_i.copy(), B_i.copy()))
            while len(lst) < count:
                lst.append(self.system(i, rng.choice([-1.0, 1.0], size=self.p[i])))
            out.append(lst)
        return out

    @classmethod
    def from_elements(
        cls,
        A: np.ndarray,
        B: np.ndarray,
        elements: Sequence[Sequence[UncertainElement]],
        labels: Optional[Sequence[Sequence[str]]] = None,
    ) -> "ElementBox":
        """The box of ``elements[i]`` (A and B elements of vertex i with [lower, upper]); the B
        elements become the common hull of :func:`input_hull` (vertex-varying B entries too)."""
        A = np.asarray(A, dtype=float)
        B = np.asarray(B, dtype=float)
        if len(elements) != A.shape[0]:
            raise ConfigError(
                f"element box: {len(elements)} element lists for {A.shape[0]} vertices"
            )
        n, m = B.shape[1:]
        base, hull, _, _ = input_hull(B, elements)
        Bc = base.copy()
        b_rows, b_cols, b_half = [], [], []
        for e in hull:
            Bc[e.row, e.col] = 0.5 * (e.lower + e.upper)
            b_rows.append(e.row)
            b_cols.append(n + e.col)
            b_half.append(0.5 * (e.upper - e.lower))
        Ac = A.copy()
        rows, cols, half, labs = [], [], [], []
        for i, els in enumerate(elements):
            r_, c_, h_, l_ = [], [], [], []
            for k, e in enumerate(els):
                if e.matrix != "A":
                    continue
                if not (0 <= e.row < n and 0 <= e.col < n):
                    raise ConfigError(
                        f"element box: vertex {i}: A[{e.row},{e.col}] outside {n} x {n}"
                    )
                Ac[i, e.row, e.col] = 0.5 * (e.lower + e.upper)
                if e.upper > e.lower:
                    r_.append(e.row)
                    c_.append(e.col)
                    h_.append(0.5 * (e.upper - e.lower))
                    l_.append(labels[i][k] if labels is not None else "")
            rows.append(np.array(r_ + b_rows, dtype=int))
            cols.append(np.array(c_ + b_cols, dtype=int))
            half.append(np.array(h_ + b_half, dtype=float))
            labs.append(tuple(l_) + ("B hull",) * len(b_rows))
        return cls(Ac, Bc, tuple(rows), tuple(cols), tuple(half), tuple(labs))


def corner_box(model: "PolytopicModel") -> Optional[ElementBox]:
    """The :class:`ElementBox` whose corners are exactly ``model.systems`` when every vertex's
    systems are all 2^q corners of a box of q single elements of [A, B] and the B part is the same
    at every vertex (the corner polytopes of :func:`uncertainty_vertices`, :func:`product_systems`
    and the influence / box reductions); None otherwise. Then the Eq. (23) polytope of each vertex
    is that box, and an LMI that holds on the box holds at every corner."""
    n = model.n_x
    rows, cols, half, centres = [], [], [], []
    b_ref = None
    for lst in model.systems:
        AB = np.array(
            [
                np.concatenate([np.asarray(a, dtype=float), np.asarray(b, dtype=float)], axis=1)
                for a, b in lst
            ]
        )
        lo, hi = AB.min(axis=0), AB.max(axis=0)
        r, c = np.nonzero(hi > lo)
        q = r.size
        if len(lst) != 2**q:
            return None
        # every system must be a corner (each varying entry at lo or hi), each corner once
        at_hi = np.isclose(AB[:, r, c], hi[r, c], rtol=0, atol=0)
        at_lo = np.isclose(AB[:, r, c], lo[r, c], rtol=0, atol=0)
        if not np.all(at_hi | at_lo):
            return None
        codes = (
            at_hi.astype(np.int64) @ (1 << np.arange(q, dtype=np.int64))
            if q
            else np.zeros(1, np.int64)
        )
        if np.unique(codes).size != len(lst):
            return None
        bpart = [
            (int(a), int(b), float(lo[a, b]), float(hi[a, b])) for a, b in zip(r, c) if b >= n
        ]
        fixed_b = 0.5 * (lo[:, n:] + hi[:, n:])
        if b_ref is None:
            b_ref = (bpart, fixed_b)
        elif bpart != b_ref[0] or not np.array_equal(fixed_b, b_ref[1]):
            return None
        order = np.argsort(c >= n, kind="stable")  # A elements first, then the B part
        rows.append(r[order])
        cols.append(c[order])
        half.append(0.5 * (hi[r, c] - lo[r, c])[order])
        centres.append(0.5 * (lo + hi))
    Ac = np.array([ctr[:, :n] for ctr in centres])
    return ElementBox(
        Ac,
        centres[0][:, n:],
        tuple(rows),
        tuple(cols),
        tuple(half),
        tuple(("corner polytope",) * int(np.size(r)) for r in rows),
    )


# --------------------------------------------------------------------------- the polytope
@dataclass
class PolytopicModel:
    """Nominal vertex systems, equilibria and nested uncertainty vertices (Eqs. 20-23).

    ``A`` (N, n, n), ``B`` (N, n, m), ``x0`` (N, n), ``u0`` (N, m) in the vertex order of
    :func:`box_vertices`; ``systems[i]`` is the list of (A_i^j, B_i^j) of Eq. (23) (defaults to
    the nominal vertex only). ``ts`` is None for continuous time, else the sample time.
    """

    vmin: np.ndarray
    vmax: np.ndarray
    A: np.ndarray
    B: np.ndarray
    x0: np.ndarray
    u0: np.ndarray
    systems: list = field(default_factory=list)
    ts: Optional[float] = None
    state_names: tuple = ()
    input_names: tuple = ()
    scheduling_names: tuple = ()
    #: set when the input matrices of ``systems`` are the common corners B^b in product order
    #: (j = a * M_B + b, see :func:`product_systems`); None = per-vertex B_i^j (vertices only).
    common_input: Optional[CommonInputSet] = None
    #: set when the certified set is the whole element box (``systems`` then holds a finite
    #: sample of it, :meth:`ElementBox.sample_systems`); None = the polytope ``systems`` itself.
    box: Optional[ElementBox] = None

    def __post_init__(self) -> None:
        self.vmin, self.vmax = _check_box(self.vmin, self.vmax)
        p = self.vmin.size
        N = 2**p
        self.A = np.asarray(self.A, dtype=float)
        self.B = np.asarray(self.B, dtype=float)
        if self.A.ndim != 3 or self.A.shape[0] != N or self.A.shape[1] != self.A.shape[2]:
            raise ConfigError(
                f"A must have shape ({N}, n, n) for a {p}-axis box, got {self.A.shape}"
            )
        n = self.A.shape[1]
        if self.B.ndim != 3 or self.B.shape[:2] != (N, n):
            raise ConfigError(f"B must have shape ({N}, {n}, m), got {self.B.shape}")
        m = self.B.shape[2]
        self.x0 = np.zeros((N, n)) if self.x0 is None else np.asarray(self.x0, dtype=float)
        self.u0 = np.zeros((N, m)) if self.u0 is None else np.asarray(self.u0, dtype=float)
        if self.x0.shape != (N, n):
            raise ConfigError(f"x0 must have shape ({N}, {n}), got {self.x0.shape}")
        if self.u0.shape != (N, m):
            raise ConfigError(f"u0 must have shape ({N}, {m}), got {self.u0.shape}")
        for name in ("A", "B", "x0", "u0"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ConfigError(f"{name} contains NaN/inf")
        if not self.systems:
            self.systems = [[(self.A[i], self.B[i])] for i in range(N)]
        if len(self.systems) != N:
            raise ConfigError(
                f"systems: need one list of uncertainty vertices per scheduling vertex ({N}), "
                f"got {len(self.systems)}"
            )
        for i, lst in enumerate(self.systems):
            if len(lst) == 0:
                raise ConfigError(f"systems[{i}] is empty")
            for j, (Aj, Bj) in enumerate(lst):
                if np.shape(Aj) != (n, n) or np.shape(Bj) != (n, m):
                    raise ConfigError(
                        f"systems[{i}][{j}]: shapes {np.shape(Aj)}, {np.shape(Bj)} "
                        f"!= ({n},{n}), ({n},{m})"
                    )
                if not (np.all(np.isfinite(Aj)) and np.all(np.isfinite(Bj))):
                    raise ConfigError(f"systems[{i}][{j}] contains NaN/inf")
        if self.common_input is not None:
            MB = self.common_input.M
            if np.shape(self.common_input.corners)[1:] != (n, m) or MB == 0:
                raise ConfigError(
                    f"common_input.corners must have shape (M_B, {n}, {m}), "
                    f"got {np.shape(self.common_input.corners)}"
                )
            bad = [i for i, lst in enumerate(self.systems) if len(lst) % MB]
            if bad:
                raise ConfigError(
                    f"common_input: systems of vertices {bad} are not a product with the "
                    f"M_B = {MB} input corners"
                )
        if self.ts is not None and not (np.isfinite(self.ts) and self.ts > 0):
            raise ConfigError(f"sample time must be > 0, got {self.ts!r}")
        if self.box is not None and (self.box.N != N or self.box.n != n or self.box.m != m):
            raise ConfigError(
                f"box: {self.box.N} vertices, {self.box.n} states, {self.box.m} inputs do not "
                "match "
                f"the model ({N}, {n}, {m})"
            )

    # sizes
    @property
    def n_vertices(self) -> int:
        return self.A.shape[0]

    @property
    def n_x(self) -> int:
        return self.A.shape[1]

    @property
    def n_u(self) -> int:
        return self.B.shape[2]

    @property
    def input_structure(self) -> dict:
        """{"B": "common" | "per_vertex", "M": [M_i], "M_A": [M_A,i], "M_B": M_B} (certificate
        entry)."""
        M = [len(lst) for lst in self.systems]
        if self.box is not None:
            return {
                "B": "common",
                "M": M,
                "M_A": M,
                "M_B": 1,
                "B_method": "element box",
                "p": self.box.p,
            }
        if self.common_input is None:
            return {"B": "per_vertex", "M": M, "M_A": M, "M_B": 1}
        MB = self.common_input.M
        return {
            "B": "common",
            "M": M,
            "M_A": [k // MB for k in M],
            "M_B": MB,
            "B_method": self.common_input.method,
        }

    @property
    def vertices(self) -> np.ndarray:
        return box_vertices(self.vmin, self.vmax)

    @classmethod
    def from_uncertain_elements(
        cls,
        vmin,
        vmax,
        A,
        B,
        x0,
        u0,
        elements: Sequence[Sequence[UncertainElement]],
        max_corners: int = MAX_CORNERS_DEFAULT,
        **kw,
    ) -> "PolytopicModel":
        """Build the nested polytope of Eq. (23) by corner enumeration per vertex."""
        A = np.asarray(A, dtype=float)
        B = np.asarray(B, dtype=float)
        if len(elements) != A.shape[0]:
            raise ConfigError(
                f"need one list of uncertain elements per vertex ({A.shape[0]}), got "
                f"{len(elements)}"
            )
        systems = [
            uncertainty_vertices(A[i], B[i], elements[i], max_corners) for i in range(A.shape[0])
        ]
        return cls(vmin=vmin, vmax=vmax, A=A, B=B, x0=x0, u0=u0, systems=systems, **kw)

    @classmethod
    def from_common_input(
        cls,
        vmin,
        vmax,
        A,
        B,
        x0,
        u0,
        elements: Sequence[Sequence[UncertainElement]],
        max_corners: int = MAX_CORNERS_DEFAULT,
        **kw,
    ) -> "PolytopicModel":
        """Eq. (23) with a common input set: per-vertex A corners (the A elements of
        ``elements[i]``) times the corners of the B hull (:func:`input_hull`), module docstring."""
        A = np.asarray(A, dtype=float)
        B = np.asarray(B, dtype=float)
        if len(elements) != A.shape[0]:
            raise ConfigError(
                f"need one list of uncertain elements per vertex ({A.shape[0]}), got "
                f"{len(elements)}"
            )
        base, hull, nlo, nhi = input_hull(B, elements)
        common = CommonInputSet(
            input_corners(base, hull, max_corners), tuple(hull), nlo, nhi, "box"
        )
        a_corners = [
            [
                a
                for a, _ in uncertainty_vertices(
                    A[i],
                    B[i],
                    [e for e in elements[i] if e.matrix == "A"],
                    max(1, max_corners // common.M),
                )
            ]
            for i in range(A.shape[0])
        ]
        return cls(
            vmin=vmin,
            vmax=vmax,
            A=A,
            B=B,
            x0=x0,
            u0=u0,
            systems=product_systems(a_corners, common),
            common_input=common,
            **kw,
        )

    @classmethod
    def from_vertex_systems(
        cls, vmin, vmax, uncertain_vertices: Sequence, x0, u0, **kw
    ) -> "PolytopicModel":
        """Build from per-vertex objects with ``A``, ``B`` and ``systems`` (the explicit list of
        Eq. (23) systems, e.g. :class:`lpv_sysid.ident.uncertainty.UncertainVertex`)."""
        return cls(
            vmin=vmin,
            vmax=vmax,
            A=np.array([uv.A for uv in uncertain_vertices]),
            B=np.array([uv.B for uv in uncertain_vertices]),
            x0=x0,
            u0=u0,
            systems=[
                [(np.asarray(a), np.asarray(b)) for a, b in uv.systems]
                for uv in uncertain_vertices
            ],
            **kw,
        )

    # interpolation (seed 0 Eq. 21, Eq. 31, Eq. 34)
    def weights(self, v_d) -> tuple[np.ndarray, bool]:
        return multilinear_weights(v_d, self.vmin, self.vmax)

    def interpolate(self, stack: np.ndarray, v_d) -> np.ndarray:
        """sum_i alpha_i(v_d) stack[i] for a vertex-stacked array (N, ...)."""
        alpha, _ = self.weights(v_d)
        return np.tensordot(alpha, np.asarray(stack, dtype=float), axes=1)

    def A_at(self, v_d) -> np.ndarray:
        return self.interpolate(self.A, v_d)

    def B_at(self, v_d) -> np.ndarray:
        return self.interpolate(self.B, v_d)

    def x0_at(self, v_d) -> np.ndarray:
        return self.interpolate(self.x0, v_d)

    def u0_at(self, v_d) -> np.ndarray:
        return self.interpolate(self.u0, v_d)

    def dx0_dvd(self, v_d) -> np.ndarray:
        """d x0 / d v_d of seed 0 Eq. (34), shape (n, p): sum_i x0_i (d alpha_i / d v_d)^T."""
        grad = multilinear_weight_gradient(v_d, self.vmin, self.vmax)
        return self.x0.T @ grad


class ScheduledLpv:
    """Nominal LPV model plus vertex gains, evaluated at v_d.

    Implements the ``ScheduledModel`` protocol of :mod:`lpv_sysid.sim.lpv_closed_loop`
    (A, B, K, x0, u0, dx0_dvd at a scheduling point), K(v_d) = sum alpha_i K_i (Eq. 31).
    """

    def __init__(self, model: PolytopicModel, K: np.ndarray) -> None:
        K = np.asarray(K, dtype=float)
        if K.shape != (model.n_vertices, model.n_u, model.n_x):
            raise ConfigError(
                f"K must have shape ({model.n_vertices}, {model.n_u}, {model.n_x}), got {K.shape}"
            )
        self.model = model
        self.Kv = K

    def A(self, v_d):
        return self.model.A_at(v_d)

    def B(self, v_d):
        return self.model.B_at(v_d)

    def K(self, v_d):
        return self.model.interpolate(self.Kv, v_d)

    def x0(self, v_d):
        return self.model.x0_at(v_d)

    def u0(self, v_d):
        return self.model.u0_at(v_d)

    def dx0_dvd(self, v_d):
        return self.model.dx0_dvd(v_d)


def interpolate_gain(K: np.ndarray, v_d, vmin, vmax) -> np.ndarray:
    """K(v_d) = sum_i alpha_i(v_d) K_i, seed 0 Eq. (31) (K: (N, m, n))."""
    alpha, _ = multilinear_weights(v_d, vmin, vmax)
    return np.tensordot(alpha, np.asarray(K, dtype=float), axes=1)


def iter_systems(model: PolytopicModel) -> Iterable[tuple[int, int, np.ndarray, np.ndarray]]:
    """(i, j, A_i^j, B_i^j) over the nested polytope of Eq. (23)."""
    for i, lst in enumerate(model.systems):
        for j, (Aj, Bj) in enumerate(lst):
            yield i, j, np.asarray(Aj, dtype=float), np.asarray(Bj, dtype=float)


def common_input_deviation(model: PolytopicModel, M_B: int) -> tuple[float, float]:
    """How far ``model.systems`` is from the common-input product structure with M_B corners.

    Returns (dB, dA): dB = max |B_i^(a,b) - B_0^(0,b)| over all i, a, b (B^b identical across
    scheduling vertices and A-corners), dA = max |A_i^(a,b) - A_i^(a,0)| (A part independent of b).
    inf when a vertex's M_i is not a multiple of M_B. Pure numpy, independent of
    :class:`CommonInputSet` (used by the verifier).
    """
    if M_B < 1 or any(len(lst) % M_B for lst in model.systems):
        return float("inf"), float("inf")
    ref = [np.asarray(model.systems[0][b][1], dtype=float) for b in range(M_B)]
    dB = dA = 0.0
    for lst in model.systems:
        for j, (Aj, Bj) in enumerate(lst):
            a, b = divmod(j, M_B)
            dB = max(dB, float(np.max(np.abs(np.asarray(Bj, dtype=float) - ref[b]))))
            dA = max(
                dA,
                float(
                    np.max(
                        np.abs(
                            np.asarray(Aj, dtype=float) - np.asarray(lst[a * M_B][0], dtype=float)
                        )
                    )
                ),
            )
    return dB, dA
