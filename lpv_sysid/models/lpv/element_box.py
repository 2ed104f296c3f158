"""The full identified box of seed 0 Eq. (22) as a structured perturbation (LFT form).

The full identified box as a structured perturbation (:class:`ElementBox`). Corner enumeration of
Eq. (23) is exponential in the number of uncertain elements (~50 per vertex for the quadrotor), so
the whole Eq. (22) box -- every identified element in its interval -- is written instead in the
linear-fractional (LFT) form of a structured, norm-bounded perturbation of the box centre:

    [A_i(delta), B(delta)] = [A_c,i, B_c] + sum_l delta_l h_l e_(r_l) e_(c_l)^T,   |delta_l| <= 1,

one scalar delta_l per element l of vertex i (row r_l, column c_l of [A, B], half-width h_l). The
B elements are the common input hull of :func:`~lpv_sysid.models.lpv.uncertainty.input_hull`
(the argument of that module's docstring: B carries no vertex index, so the interior of the
scheduling box is covered). The multipliers that turn this
into a finite LMI are in :mod:`lpv_sysid.synthesis.robust`. Corner polytopes of single-element
boxes (the influence / box reductions of :mod:`lpv_sysid.ident.vertex.uncertainty`) have the same
form (:func:`corner_box`), which is how the seed-size problem is solved with one block per vertex.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.lpv.uncertainty import UncertainElement, input_hull


# --------------------------------------------------------------------------- element box (LFT)
@dataclass(frozen=True)
class ElementBox:
    """Every uncertain element of every vertex in its interval, as the structured perturbation of
    the module docstring: ``[A_i(delta), B(delta)] = [A_c[i], B_c] + sum_l delta_l h_l e_r e_c^T``.

    ``A_centre`` (N, n, n) and ``B_centre`` (n, m) are the interval midpoints (elements that are
    not uncertain keep the vertex value; B is common to all vertices). Per vertex i the elements
    are ``rows[i]``, ``cols[i]`` (column of [A, B]: ``c < n`` an A element, ``c >= n`` the B
    element (r, c - n)) and ``half[i]`` (> 0); the B elements are the same at every vertex (the
    common hull) and come after the A elements. ``labels[i]`` say where each interval came from;
    ``coverage``: with which joint probability the intervals hold the identified elements (the
    certificate's ``certified_set.joint_coverage``; None: marginal intervals as stored).
    """

    A_centre: np.ndarray
    B_centre: np.ndarray
    rows: tuple
    cols: tuple
    half: tuple
    labels: tuple = ()
    coverage: Optional[dict] = None

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


def corner_box(systems: Sequence[Sequence[tuple]]) -> Optional[ElementBox]:
    """The :class:`ElementBox` whose corners are exactly ``systems`` when every vertex's
    systems are all 2^q corners of a box of q single elements of [A, B] and the B part is the same
    at every vertex (the corner polytopes of :func:`uncertainty_vertices`, :func:`product_systems`
    and the influence / box reductions); None otherwise. Then the Eq. (23) polytope of each vertex
    is that box, and an LMI that holds on the box holds at every corner. ``systems``: per vertex
    the list of its (A, B) systems (``PolytopicModel.systems``)."""
    n = np.asarray(systems[0][0][0]).shape[0]
    rows, cols, half, centres = [], [], [], []
    b_ref = None
    for lst in systems:
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
