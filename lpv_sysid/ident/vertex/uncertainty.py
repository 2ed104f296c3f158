"""Uncertainty box and uncertain vertex systems, seed 0 Eqs. (22)-(23).

Every identified element ``theta_l`` of a vertex model gets the interval
``[theta_l - k s_l, theta_l + k s_l]`` (``k`` configurable, default 3; ``s_l`` its standard
error from :mod:`lpv_sysid.ident.equation_error`, widened by ``t_factor(k, dof)`` so that the
interval keeps the normal coverage ``2 Phi(k) - 1`` when the studentised error is Student-t),
Eq. (22).  These intervals - all of them - are what ``vertex_models.yaml`` stores.  The
reductions below only decide which systems the identification itself would hand to an LMI
(``UncertainVertex.systems``, ``Interval.corner``/``half``).  The uncertain vertex system
``Lambda_i(theta)`` is then a convex combination of the ``M_i`` systems ``Lambda_i^j`` of
Eq. (23), i.e. of ``(A_i^j, B^j)`` pairs (``C`` is fixed and ``B_e = B R`` follows from ``B``).

With ``p`` identified elements the box has ``2^p`` corners (``p`` ~ 40 for the quadrotor),
which no LMI solver will take.  Three reductions are offered (``method``):

``box``      all ``2^p`` corners (exact, only for small ``p``; refused above ``max_corners``).
``influence`` (default) rank the parameters by their *influence* on the H-infinity-relevant
    frequency response ``G(jw) = C (jwI - A)^-1 B`` (``C`` selects the performance output,
    the body velocities of Eq. 18, by default), ``infl_l = halfwidth_l * max_w ||dG/dtheta_l||_F``
    with the analytic first-order sensitivities ``dG/dA_ab = C R e_a e_b^T R B`` and
    ``dG/dB_ab = C R e_a e_b^T`` (``R = (jwI - A)^-1``), keep the ``p_max`` most influential
    ones as corner parameters (``M_i = 2^p_max``) and fix the others at their nominal values.
    The dropped intervals are *absorbed* by widening the kept half-widths by the factor
    ``sum_all infl / sum_kept infl`` (>= 1): the sum of the kept first-order bounds then
    equals the first-order bound of all parameters, so the worst-case first-order
    frequency-response perturbation of the reduced polytope is at least that of the full
    box.  This is conservative in that first-order sense, not a set containment: the
    dropped elements themselves stay nominal in every corner.
``hybrid``   strict containment with few corners: the kept parameters span box corners, the
    ``q`` dropped ones are enclosed by a simplex with ``q + 1`` vertices,
    ``{theta_d >= lower_d, sum_d (theta_d - lower_d) / width_d <= q}`` (it contains the
    unit box of the dropped parameters), so ``M_i = 2^p_max (q + 1)`` and every parameter in
    the box of Eq. (22) lies in the convex hull of the generated systems.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError
from lpv_sysid.io.formats import UncertainEntry

METHODS = ("box", "influence", "hybrid")


#: most corner systems of one vertex (Eq. 23): 2^16; beyond, no LMI solver takes them
MAX_CORNERS = 65536


@dataclass(frozen=True)
class UncertaintyConfig:
    """The interval width (Eq. 22) and the reduction to corner systems (Eq. 23)."""

    k_sigma: float = cf.number(
        3.0,
        "interval = nominal +/- k_sigma std (Eq. 22); at least 1: a narrower interval covers "
        "less than 68 % of an element and the certified box (Eq. 23) misses the model",
        lo=1.0,
    )
    method: str = cf.choice("influence", METHODS, "reduction to corners (module docstring)")
    p_max: int = cf.count(4, "corner parameters per vertex, M_i = 2^p_max (Eq. 23)", hi=16)
    max_corners: int = cf.count(
        4096,
        f"box: refused above this many corners; 1 .. {MAX_CORNERS} (2^16: larger corner "
        "sets are no LMI a solver takes, the guard against 2^p corners)",
        lo=1,
        hi=MAX_CORNERS,
    )
    freq_hz: tuple[float, float] = cf.numbers(
        (0.05, 10.0),
        "band of the frequency-response influence ranking [Hz], [low, high]",
        length=2,
        lo=0.0,
        lo_open=True,
    )
    n_freq: int = cf.count(40, "frequencies of the influence ranking", lo=2, hi=10_000)
    output_states: tuple[int, ...] = cf.counts((2, 3, 4), "u, v, w: z = Q^-1 (v - v_d), Eq. (18)")
    joint_alpha: float | None = cf.number(
        None,
        "null, or widen k (sidak_k) for joint coverage 1 - alpha of all elements",
        lo=0.0,
        lo_open=True,
        hi=1.0,
        hi_open=True,
        optional=True,
    )

    @classmethod
    def from_dict(cls, d: dict | None, where: str = "uncertainty") -> "UncertaintyConfig":
        kw = cf.parse_fields(cls, d or {}, where)
        lo, hi = kw.get("freq_hz", cls.freq_hz)
        if not lo < hi:
            raise cf.error(where, "freq_hz", f"need low < high, got {[lo, hi]}")
        return cls(**kw)


@dataclass(frozen=True)
class Interval(UncertainEntry):
    """One identified element and its interval, Eq. (22): the file entry of
    ``vertex_models.yaml`` 'uncertain' (:class:`~lpv_sysid.io.formats.UncertainEntry`: ``std``
    calibrated, ``lower``/``upper`` = ``nominal -/+ k std``) plus what the reduction of Eq. (23)
    decides about it (``corner``: varied over the corners; ``half``: its half-width there,
    widened by the absorption factor; 0 for an element held at its nominal value)."""

    influence: float = 0.0
    corner: bool = False  # varied over the corners of Eq. (23)
    half: float = 0.0  # half-width used in the Eq. (23) systems

    def as_dict(self) -> dict:
        return self.to_dict()


@dataclass(frozen=True)
class UncertainVertex:
    """Nominal vertex model, its parameter box and the systems ``Lambda_i^j`` of Eq. (23)."""

    A: np.ndarray
    B: np.ndarray
    intervals: tuple[Interval, ...]
    systems: tuple[tuple[np.ndarray, np.ndarray], ...]  # (A_i^j, B^j), j = 1..M_i
    method: str
    inflation: float = 1.0

    @property
    def M(self) -> int:
        return len(self.systems)


def sidak_k(p: int, alpha: float) -> float:
    """Interval half-width in standard errors so that *all* ``p`` (independent, Gaussian)
    estimates are covered with probability ``1 - alpha`` (Sidak): ``k = Phi^-1(1 - a/2)`` with
    ``a = 1 - (1 - alpha)^(1/p)``.  ``k_sigma = 3`` covers each element with 99.7 % but all 43
    elements of a quadrotor vertex only with ~89 %; ``sidak_k(43, 0.05)`` = 3.24."""
    from scipy.stats import norm

    a = 1.0 - (1.0 - alpha) ** (1.0 / max(p, 1))
    return float(norm.ppf(1.0 - a / 2.0))


#: joint probability with which the certified element box contains *all* identified elements
#: at once (issue 20 item 4): the synthesis box and ``lpv-sysid coverage`` use it
DEFAULT_JOINT_PROBABILITY = 0.95


def joint_k(
    p_total: int,
    probability: float = DEFAULT_JOINT_PROBABILITY,
    dof: float | None = None,
    k_stored: float = 3.0,
) -> float:
    """Simultaneous half-width, in *stored* standard errors, that covers all ``p_total``
    elements at once with probability ``probability`` (Sidak: each two-sided interval at
    ``1 - a`` with ``a = 1 - probability^(1/p_total)``; by Sidak's inequality (Sidak 1967,
    JASA 62) this holds for jointly Gaussian estimates with any correlation, and
    ``probability`` is a lower bound).

    The stored std is ``s * t_factor(k_stored, dof)`` (:func:`build`): the quantile is the
    Student-t one with ``dof`` degrees of freedom (normal when None) on the raw ``s``,
    returned in units of the stored std. ``joint_k(408, 0.95)`` = 3.84 (normal), against the
    marginal 3 that covers all 408 only with 0.9973^408 ~ 33 %."""
    from lpv_sysid.ident.equation_error import t_factor, upper_quantile

    if not 0.0 < probability < 1.0:
        raise ConfigError(f"joint probability must be in (0, 1), got {probability!r}")
    a = 1.0 - probability ** (1.0 / max(int(p_total), 1))
    if dof is not None and not np.isfinite(dof):
        dof = None
    q = upper_quantile(a / 2.0, dof)  # norm.isf / t.isf, without importing scipy.stats
    return q / t_factor(k_stored, dof)


def intervals_from_elements(elements, k_sigma: float, std_factor: float = 1.0) -> list[Interval]:
    """``elements``: iterable of (matrix, row, col, nominal, std) (``Fit.elements()``); the
    stored standard error is ``std * std_factor`` (the finite-sample widening of
    :func:`lpv_sysid.ident.equation_error.t_factor`)."""
    out = []
    for m, r, c, nom, s in elements:
        if not (np.isfinite(nom) and np.isfinite(s) and s >= 0):
            raise ConfigError(f"{m}[{r},{c}]: non-finite nominal or standard error ({nom}, {s})")
        s = s * std_factor
        out.append(
            Interval(m, int(r), int(c), float(nom), float(s), nom - k_sigma * s, nom + k_sigma * s)
        )
    return out


def influence(
    A: np.ndarray,
    B: np.ndarray,
    intervals: Sequence[Interval],
    cfg: UncertaintyConfig = UncertaintyConfig(),
) -> np.ndarray:
    """``halfwidth_l * max_w ||dG(jw)/dtheta_l||_F`` for every interval (see module docstring)."""
    n = A.shape[0]
    C = np.eye(n)[list(cfg.output_states)]
    w = 2 * np.pi * np.geomspace(cfg.freq_hz[0], cfg.freq_hz[1], cfg.n_freq)
    col_norm = np.zeros((w.size, n))  # ||C R e_a||
    row_norm = np.zeros((w.size, n))  # ||e_b^T R B||
    eye = np.eye(n)
    for q, wq in enumerate(w):
        # scipy.linalg.solve would do the same; numpy's batched solve is enough for 12 x 12
        R = np.linalg.solve(1j * wq * eye - A, eye)
        col_norm[q] = np.linalg.norm(C @ R, axis=0)
        row_norm[q] = np.linalg.norm(R @ B, axis=1)
    out = np.zeros(len(intervals))
    for idx, iv in enumerate(intervals):
        half = 0.5 * (iv.upper - iv.lower)
        if iv.matrix == "A":
            sens = np.max(col_norm[:, iv.row] * row_norm[:, iv.col])
        else:
            sens = np.max(col_norm[:, iv.row])
        out[idx] = half * sens
    return out


def _apply(A: np.ndarray, B: np.ndarray, ivs: Sequence[Interval], values: Sequence[float]):
    Aj, Bj = A.copy(), B.copy()
    for iv, val in zip(ivs, values):
        (Aj if iv.matrix == "A" else Bj)[iv.row, iv.col] = val
    return Aj, Bj


def applied_k(cfg: UncertaintyConfig, p: int) -> float:
    """Half-width of Eq. (22) in standard errors: ``k_sigma``, raised to the Sidak value for
    ``p`` elements when ``joint_alpha`` is set."""
    k = cfg.k_sigma
    if cfg.joint_alpha is not None:
        k = max(k, sidak_k(p, cfg.joint_alpha))
    return float(k)


def build(
    A: np.ndarray,
    B: np.ndarray,
    elements,
    cfg: UncertaintyConfig = UncertaintyConfig(),
    dof: float | None = None,
) -> UncertainVertex:
    """Intervals (Eq. 22) and uncertain vertex systems (Eq. 23) for one LPV vertex.

    ``dof``: Student-t degrees of freedom of the studentised estimates (``Fit.dof``); the
    standard errors are widened by ``t_factor(k, dof)`` so that ``nominal +/- k std`` keeps the
    normal coverage ``2 Phi(k) - 1`` (None: no widening).
    """
    from lpv_sysid.ident.equation_error import t_factor

    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    elements = list(elements)
    k = applied_k(cfg, len(elements))
    ivs = intervals_from_elements(elements, k, t_factor(k, dof))
    if cfg.output_states and max(cfg.output_states) >= A.shape[0]:
        raise ConfigError(
            f"uncertainty.output_states {cfg.output_states} out of range for n_x={A.shape[0]}"
        )
    infl = influence(A, B, ivs, cfg) if ivs else np.zeros(0)
    p = len(ivs)
    if cfg.method == "box" or p <= cfg.p_max:
        if 2**p > cfg.max_corners:
            raise ConfigError(
                f"uncertainty.method 'box' needs 2^{p} corners (> max_corners "
                f"{cfg.max_corners}); use 'influence' or 'hybrid'"
            )
        kept = list(range(p))
    else:
        kept = sorted(np.argsort(-infl, kind="stable")[: cfg.p_max].tolist())
    dropped = [idx for idx in range(p) if idx not in kept]
    inflation = 1.0
    if cfg.method == "influence" and dropped:
        s_kept = float(np.sum(infl[kept]))
        inflation = float(np.sum(infl) / s_kept) if s_kept > 0 else 1.0
    marked = []
    for idx, iv in enumerate(ivs):
        is_kept = idx in kept
        half = 0.5 * (iv.upper - iv.lower) * (inflation if is_kept else 1.0)
        if not is_kept and cfg.method != "hybrid":
            half = 0.0
        marked.append(
            Interval(
                iv.matrix,
                iv.row,
                iv.col,
                iv.nominal,
                iv.std,
                iv.lower,
                iv.upper,
                float(infl[idx]),
                is_kept,
                float(half),
            )
        )
    corner_ivs = [marked[idx] for idx in kept]
    systems = []
    box_corners = list(
        itertools.product(*[(iv.nominal - iv.half, iv.nominal + iv.half) for iv in corner_ivs])
    )
    if cfg.method == "hybrid" and dropped:
        d_ivs = [marked[idx] for idx in dropped]
        q = len(d_ivs)
        lows = np.array([iv.lower for iv in d_ivs])
        widths = np.array([iv.upper - iv.lower for iv in d_ivs])
        simplex = [lows] + [lows + q * widths * np.eye(q)[j] for j in range(q)]
        if len(box_corners) * len(simplex) > cfg.max_corners:
            raise ConfigError(
                f"uncertainty 'hybrid' needs {len(box_corners) * len(simplex)} systems "
                f"(> max_corners {cfg.max_corners}); lower p_max"
            )
        for corner in box_corners:
            Ak, Bk = _apply(A, B, corner_ivs, corner)
            for s in simplex:
                systems.append(_apply(Ak, Bk, d_ivs, s))
    else:
        for corner in box_corners:
            systems.append(_apply(A, B, corner_ivs, corner))
    return UncertainVertex(A, B, tuple(marked), tuple(systems), cfg.method, inflation)


def contains(
    uv: UncertainVertex, A_true: np.ndarray, B_true: np.ndarray, tol: float = 1e-9
) -> bool:
    """Is ``(A_true, B_true)`` a convex combination of the systems ``Lambda_i^j`` (Eq. 23)?

    Solved as a linear feasibility problem with ``scipy.optimize.linprog`` over the
    identified elements (all systems agree elsewhere; those elements are compared directly).
    """
    from scipy.optimize import linprog

    idx = [(iv.matrix, iv.row, iv.col) for iv in uv.intervals]

    def vec(Am, Bm):
        return np.array([(Am if m == "A" else Bm)[r, c] for m, r, c in idx])

    V = np.array([vec(Aj, Bj) for Aj, Bj in uv.systems]).T  # (p, M)
    target = vec(A_true, B_true)
    # every element outside the identified set must equal the nominal one
    mask = np.ones_like(uv.A, dtype=bool)
    maskb = np.ones_like(uv.B, dtype=bool)
    for m, r, c in idx:
        (mask if m == "A" else maskb)[r, c] = False
    if not (
        np.allclose(A_true[mask], uv.A[mask], atol=tol)
        and np.allclose(B_true[maskb], uv.B[maskb], atol=tol)
    ):
        return False
    M = V.shape[1]
    scale = np.maximum(np.abs(V).max(axis=1), 1e-12)
    A_eq = np.vstack([V / scale[:, None], np.ones((1, M))])
    b_eq = np.concatenate([target / scale, [1.0]])
    res = linprog(np.zeros(M), A_eq=A_eq, b_eq=b_eq, bounds=[(0, None)] * M, method="highs")
    return bool(res.status == 0)
