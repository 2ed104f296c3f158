"""Empirical Monte Carlo over the FULL identified uncertainty box: evidence, not a certificate.

Rows ``full-box hinf``, ``full-box frac``, ``full-box stab`` (:mod:`lpv_sysid.synthesis.verify`
item 5). Scheduling points v_d (the box corners, then uniform interior points) and, independently
per scheduling vertex i, every identified element theta_i,l from its full interval
(:func:`lpv_sysid.synthesis.verify.intervals.full_box_intervals`; even samples uniform in the
box, odd samples a random corner of it) give A(v_d) = sum_i alpha_i A_i(theta_i), B(v_d) likewise
(Eq. 21, multilinear alpha) and the interpolated gain K(v_d) (Eq. 31); the frozen closed loop
A + B K is judged by its spectral abscissa and H-inf norm u_e -> z
(:func:`lpv_sysid.synthesis.hinf.norm.hinf_norm`). Two extreme corners per scheduling vertex are
added: every element at the end of its interval that increases, to first order, (a) the
closed-loop H-inf norm (analytic sensitivity of sigma_max at the peak frequency) and (b) the
spectral abscissa (eigenvalue sensitivity y^H dA x / y^H x).

Sampling proves nothing about the samples not drawn. For a reduced-polytope certificate, which
does not claim this set, a miss is advisory (WARN) unless ``strict``; for a full-box certificate
the Monte Carlo is a cross-check of the claim and a miss fails.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.lpv import PolytopicModel, multilinear_weights
from lpv_sysid.parallel import Batch, map_tasks, resolve_workers, start_tasks
from lpv_sysid.synthesis.hinf import hinf_norm
from lpv_sysid.synthesis.verify.intervals import DEFAULT_K_SIGMA, ElementBox


@dataclass
class FullBoxSample:
    where: str  # "corner 3 uniform", "interior 17 corner-draw", "vertex 2 worst-norm corner"
    v_d: np.ndarray
    norm: float  # H-inf norm u_e -> z (inf when unstable; nan in discrete time)
    abscissa: float  # max Re eig (continuous) or spectral radius - 1 (discrete)
    ok: bool


@dataclass
class FullBoxResult:
    """Outcome of :func:`full_box_check` (empirical, not certified)."""

    samples: list
    gamma: float
    k_sigma: float
    k_source: str
    seed: int
    n_elements: list  # identified elements per vertex
    n_stored: int  # elements using the stored [lower, upper] (all vertices)
    n_ksigma: int  # elements using nominal +/- k std
    worst: Optional[FullBoxSample] = None
    worst_A: Optional[np.ndarray] = None  # frozen closed-loop data of the worst sample
    worst_B: Optional[np.ndarray] = None
    worst_K: Optional[np.ndarray] = None

    @property
    def n(self) -> int:
        return len(self.samples)

    @property
    def fraction_ok(self) -> float:
        return sum(s.ok for s in self.samples) / max(1, self.n)

    @property
    def all_stable(self) -> bool:
        return all(s.abscissa < 0 for s in self.samples)

    @property
    def max_abscissa(self) -> float:
        return max((s.abscissa for s in self.samples), default=float("nan"))

    @property
    def passed(self) -> bool:
        return bool(self.samples) and all(s.ok for s in self.samples)

    def summary(self) -> dict:
        """Plain mapping for verification.yaml / the report."""
        w = self.worst
        return {
            "samples": self.n,
            "seed": int(self.seed),
            "gamma": float(self.gamma),
            "k_sigma": float(self.k_sigma),
            "k_sigma_source": self.k_source,
            "elements_per_vertex": [int(x) for x in self.n_elements],
            "intervals_stored": int(self.n_stored),
            "intervals_k_std": int(self.n_ksigma),
            "worst_norm": float(w.norm) if w is not None else float("nan"),
            "worst_where": w.where if w is not None else "",
            "worst_v_d": [float(x) for x in w.v_d] if w is not None else [],
            "fraction_ok": float(self.fraction_ok),
            "all_stable": bool(self.all_stable),
            "max_abscissa": float(self.max_abscissa),
            "passed": bool(self.passed),
            "note": "empirical Monte Carlo over the full identified box (evidence, not a proof)",
        }


#: below this many samples the Monte Carlo runs in this process (a spawned worker's start-up,
#: ~0.3 s, exceeds what it saves at ~0.8 ms per sample)
PARALLEL_MIN_SAMPLES = 800


def _start_judging(
    samples: "_Samples",
    ctx: tuple,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    rtol: float,
    ts: Optional[float],
    workers: Optional[int],
    backend: str = "process",
) -> Batch:
    """:func:`_frozen` of every random draw (:func:`_system`: the frozen system built where it
    is judged), in chunks on ``workers``; ``ctx``: :func:`_system`'s model data. A chunk
    carries its rows of the drawn arrays (a few arrays to pickle, not one per sample and
    vertex)."""
    n = samples.n_draws
    n_work = 1 if n < PARALLEL_MIN_SAMPLES else resolve_workers(workers)
    size = max(1, -(-n // (8 * n_work)))  # ~8 chunks per worker: load balance
    chunks = [(samples.rows(i, i + size), ctx, R, C, gamma, rtol, ts) for i in range(0, n, size)]
    return start_tasks(_judge_chunk, chunks, n_work, backend)


def _judge_chunk(chunk: tuple) -> list:
    """One chunk of :func:`_start_judging` (module level: it runs in a worker process)."""
    block, ctx, R, C, gamma, rtol, ts = chunk
    out = []
    for spec in _Samples.specs(block):
        A, B, K = _system(ctx, spec)
        out.append(_frozen(A, B, K, R, C, gamma, rtol, ts))
    return out


class _Samples:
    """The drawn samples in sample order: ``vd`` (n_draws, p) and ``thetas`` (per vertex,
    (n_draws, elements)) of the random draws, then the extreme corners (``extremes``: (where,
    v_d, (A, B, K))), each sample i a :func:`_system` spec (:meth:`spec`)."""

    def __init__(self, vd: np.ndarray, thetas: list, n_vertices: int, extremes: list):
        self.vd, self.thetas, self.extremes = vd, thetas, extremes
        self.n_draws = vd.shape[0]
        self.n_vertices = n_vertices

    @property
    def n(self) -> int:
        return self.n_draws + len(self.extremes)

    def rows(self, i: int, j: int) -> tuple:
        """Samples i..j-1 as (v_d rows, theta rows per vertex, extreme systems)."""
        a, b = min(i, self.n_draws), min(j, self.n_draws)
        ext = [e[2] for e in self.extremes[max(0, i - self.n_draws) : max(0, j - self.n_draws)]]
        return self.vd[a:b], [t[a:b] for t in self.thetas], ext

    @staticmethod
    def specs(block: tuple) -> Iterator[tuple]:
        vd, thetas, ext = block
        for k in range(vd.shape[0]):
            yield ("draw", vd[k], [t[k] for t in thetas])
        for A, B, K in ext:
            yield ("system", A, B, K)

    def spec(self, i: int) -> tuple:
        return next(self.specs(self.rows(i, i + 1)))

    def where(self, i: int) -> tuple:
        """(where, v_d) of sample i: "corner 3 uniform", "interior 17 corner-draw",
        "vertex 2 worst-norm corner"."""
        if i >= self.n_draws:
            return self.extremes[i - self.n_draws][:2]
        tag = f"corner {i}" if i < self.n_vertices else f"interior {i}"
        return f"{tag} {'corner-draw' if i % 2 == 1 else 'uniform'}", self.vd[i]


def _system(ctx: tuple, spec: tuple) -> tuple:
    """``(A, B, K)`` of one draw: ``("draw", v_d, thetas)`` -- A(v_d) = sum_i alpha_i A_i(theta_i),
    B likewise (Eq. 21), K(v_d) = sum_i alpha_i K_i (Eq. 31) -- or ``("system", A, B, K)``
    (the extreme corners, built where they were found). ``ctx``: (A_i, B_i, K_i, vmin, vmax,
    element boxes). Deterministic: the worker and this process build the same numbers."""
    if spec[0] == "system":
        return spec[1], spec[2], spec[3]
    _, vd, thetas = spec
    As, Bs, K, vmin, vmax, boxes = ctx
    alpha, _ = multilinear_weights(vd, vmin, vmax)
    A = np.zeros_like(As[0])
    B = np.zeros_like(Bs[0])
    for i, a in enumerate(alpha):
        if a == 0.0:
            continue
        Ai, Bi = boxes[i].apply(As[i], Bs[i], thetas[i])
        A += a * Ai
        B += a * Bi
    return A, B, np.tensordot(alpha, K, axes=1)


def _frozen(
    A: np.ndarray,
    B: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    rtol: float,
    ts: Optional[float],
) -> tuple[float, float, bool]:
    """(norm, abscissa, ok) of the frozen closed loop A + B K (seed 0 Eq. 19 with Eq. 31)."""
    Acl = A + B @ K
    eig = np.linalg.eigvals(Acl)
    if ts is not None:
        rho = float(np.max(np.abs(eig))) - 1.0
        return float("nan"), rho, rho < 0.0
    absc = float(np.max(eig.real))
    if absc >= 0.0:
        return float("inf"), absc, False
    h = hinf_norm(Acl, B @ R, C)
    return float(h.value), absc, bool(h.stable and h.lower <= gamma * (1 + rtol))


def _worst_corners(
    A: np.ndarray,
    B: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    box: ElementBox,
    ts: Optional[float],
) -> list:
    """First-order worst corners of the element box at one scheduling vertex: every element at the
    end of its interval that increases (a) the H-inf norm and (b) the spectral abscissa, to first
    order at the box centre (:func:`element_sensitivities`)."""
    if box.is_a.size == 0:
        return []
    th0 = 0.5 * (box.lower + box.upper)
    return [
        (name, np.where(g > 0, box.upper, box.lower))
        for name, g in element_sensitivities(A, B, K, R, C, box, th0, ts)
    ]


def element_sensitivities(
    A: np.ndarray,
    B: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    box: ElementBox,
    theta: np.ndarray,
    ts: Optional[float] = None,
) -> list:
    """[("worst-norm corner", d||G||_inf/d theta),
    ("worst-abscissa corner", d max Re lambda/d theta)] of the frozen closed loop at ``theta``
    (the norm entry only when stable, continuous time).

    d sigma = Re(u^H dG v) at the peak frequency w (u, v top singular vectors of G(j w)),
    dG = C Rz dAcl Rz Be + C Rz dBe, Rz = (j w I - Acl)^-1, dAcl = dA + dB K, dBe = dB R;
    d lambda = y^H dAcl x / (y^H x) for the rightmost eigenvalue (x right, y left eigenvector).
    Hand-written: scipy has no H-inf sensitivity."""
    if box.is_a.size == 0:
        return []
    A0, B0 = box.apply(A, B, theta)
    Acl = A0 + B0 @ K
    eig, yl, xr = _eig_lr(Acl)
    k = int(np.argmax(eig.real))
    x, y = xr[:, k], yl[:, k]
    yx = np.vdot(y, x)
    grads = []
    if ts is None and eig[k].real < 0:
        h = hinf_norm(Acl, B0 @ R, C)
        w = _refine_peak(Acl, B0 @ R, C, h.frequency if np.isfinite(h.frequency) else 0.0)
        n = Acl.shape[0]
        Rz = np.linalg.inv(1j * w * np.eye(n) - Acl)
        G = C @ Rz @ (B0 @ R)
        U, _, Vh = np.linalg.svd(G)
        u, v = U[:, 0], Vh[0].conj()
        p = u.conj() @ C @ Rz  # (n,)
        q = Rz @ (B0 @ R) @ v  # (n,)
        g = np.empty(box.is_a.size)
        a, b = box.is_a, ~box.is_a
        g[a] = np.real(p[box.row[a]] * q[box.col[a]])
        g[b] = np.real(p[box.row[b]] * ((K @ q)[box.col[b]] + (R @ v)[box.col[b]]))
        grads.append(("worst-norm corner", g))
    if abs(yx) > 0:
        g = np.empty(box.is_a.size)
        a, b = box.is_a, ~box.is_a
        g[a] = np.real(np.conj(y[box.row[a]]) * x[box.col[a]] / yx)
        g[b] = np.real(np.conj(y[box.row[b]]) * (K @ x)[box.col[b]] / yx)
        grads.append(("worst-abscissa corner", g))
    return grads


def _refine_peak(A: np.ndarray, B: np.ndarray, C: np.ndarray, w0: float) -> float:
    """Peak frequency of sigma_max near the bisection's w0 (its bracket ends at a midpoint, O(dw)
    off the maximiser; the envelope-theorem gradient needs the maximiser). scipy bounded Brent."""
    from scipy.optimize import minimize_scalar

    from lpv_sysid.synthesis.hinf import sigma_max

    if w0 <= 0.0:
        return 0.0
    r = minimize_scalar(
        lambda w: -sigma_max(A, B, C, w),
        bounds=(0.8 * w0, 1.25 * w0),
        method="bounded",
        options={"xatol": 1e-10 * w0},
    )
    return float(r.x) if -r.fun >= sigma_max(A, B, C, w0) else w0


def _eig_lr(M: np.ndarray):
    from scipy.linalg import eig

    w, vl, vr = eig(M, left=True, right=True)
    return w, vl, vr


def full_box_check(
    model: PolytopicModel,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    boxes: list,
    n: int = 200,
    seed: int = 0,
    rtol: float = 1e-6,
    extremes: bool = True,
    k_sigma: float = DEFAULT_K_SIGMA,
    k_source: str = "",
    workers: Optional[int] = 1,
    backend: str = "process",
) -> FullBoxResult:
    """Monte Carlo over the full identified box (module docstring, item 5); empirical only:
    :func:`start_full_box_check` and its result."""
    return start_full_box_check(
        model, K, R, C, gamma, boxes, n, seed, rtol, extremes, k_sigma, k_source, workers, backend
    ).result()


def start_full_box_check(
    model: PolytopicModel,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    boxes: list,
    n: int = 200,
    seed: int = 0,
    rtol: float = 1e-6,
    extremes: bool = True,
    k_sigma: float = DEFAULT_K_SIGMA,
    k_source: str = "",
    workers: Optional[int] = 1,
    backend: str = "process",
) -> "PendingFullBox":
    """The samples of :func:`full_box_check` drawn and handed to the workers; returns at once
    (the caller runs its other checks meanwhile; :meth:`PendingFullBox.result` collects).

    ``boxes``: :func:`full_box_intervals` (one per vertex, box order). Samples: the 2^p scheduling
    corners first (when n allows), then uniform interior v_d; per sample and per vertex the
    elements are drawn independently, uniform in their interval (even samples) or at a random
    corner of it (odd samples). ``extremes`` adds the two first-order worst corners per scheduling
    vertex (:func:`_worst_corners`). Seeded: same inputs and seed -> same samples.

    The samples are drawn first (in this process, in the order above), then judged in chunks
    on ``workers`` processes (:func:`lpv_sysid.parallel.start_tasks`; ``None``: every core) --
    the same numbers as the serial run for any ``workers``. Fewer than
    :data:`PARALLEL_MIN_SAMPLES` random draws are judged here (starting a worker costs more).
    The extreme corners are found while the workers run and judged here, one BLAS thread, in
    :meth:`PendingFullBox.result` (their sample order stays last).
    """
    if len(boxes) != model.n_vertices:
        raise ConfigError(
            f"full-box check: {len(boxes)} element boxes for {model.n_vertices} vertices"
        )
    for i, b in enumerate(boxes):
        n_col = np.where(b.is_a, model.n_x, model.n_u)
        if b.row.size and (
            np.any(b.row < 0)
            or np.any(b.row >= model.n_x)
            or np.any(b.col < 0)
            or np.any(b.col >= n_col)
        ):
            raise ConfigError(
                f"full-box check: vertex {i}: uncertain element outside "
                f"A ({model.n_x}x{model.n_x}) / B ({model.n_x}x{model.n_u})"
            )
        if np.any(b.lower > b.upper) or not np.all(np.isfinite(np.r_[b.lower, b.upper])):
            raise ConfigError(f"full-box check: vertex {i}: need finite lower <= upper")
    K = np.asarray(K, dtype=float)
    R = np.asarray(R, dtype=float)
    C = np.asarray(C, dtype=float)
    rng = np.random.default_rng(seed)
    verts = model.vertices
    res = FullBoxResult(
        [],
        float(gamma),
        float(k_sigma),
        k_source,
        int(seed),
        [b.is_a.size for b in boxes],
        sum(s == "stored" for b in boxes for s in b.source),
        sum(s == "k*std" for b in boxes for s in b.source),
    )
    # every random draw happens here (the samples do not depend on ``workers``), in sample
    # order: per sample its interior v_d (p numbers; none for a corner) and then every
    # vertex's elements (a zero weight skips a vertex in _system). Drawn in two blocks, the
    # corners' and the interior samples': Generator.random fills doubles one after another,
    # so the numbers are those of one call per sample and vertex (the loop this replaced),
    # and the arithmetic below is the same per element. The systems are built where they are
    # judged.
    n = max(0, int(n))
    p = model.vmin.size
    sizes = [int(b.lower.size) for b in boxes]
    n_el = sum(sizes)
    n_c = min(n, len(verts))
    u_c = rng.random(n_c * n_el).reshape(n_c, n_el)
    u_i = rng.random((n - n_c) * (p + n_el)).reshape(n - n_c, p + n_el)
    vd = np.vstack(
        [
            np.asarray(verts[:n_c], dtype=float).reshape(n_c, p),
            model.vmin + u_i[:, :p] * (model.vmax - model.vmin),
        ]
    )
    u = np.vstack([u_c, u_i[:, p:]])
    corner_draw = (np.arange(n) % 2 == 1)[:, None]  # odd samples: a random corner of the box
    thetas = []
    off = 0
    for b, m in zip(boxes, sizes):
        ub = u[:, off : off + m]
        off += m
        thetas.append(
            np.where(
                corner_draw,
                np.where(ub < 0.5, b.lower, b.upper),
                b.lower + ub * (b.upper - b.lower),
            )
        )
    samples = _Samples(vd, thetas, len(verts), [])
    ctx = (model.A, model.B, K, model.vmin, model.vmax, list(boxes))
    judge = (R, C, float(gamma), rtol, model.ts)
    batch = _start_judging(samples, ctx, *judge, workers, backend)  # the draws, on the workers
    try:  # meanwhile here: the extreme corners (judged here too, PendingFullBox.result)
        if extremes and n > 0:
            for i, vd_i in enumerate(verts):
                for name, th in _worst_corners(
                    model.A[i], model.B[i], K[i], R, C, boxes[i], model.ts
                ):
                    Ai, Bi = boxes[i].apply(model.A[i], model.B[i], th)
                    samples.extremes.append(
                        (f"vertex {i} {name}", np.asarray(vd_i, dtype=float), (Ai, Bi, K[i]))
                    )
    except BaseException:
        batch.cancel()
        raise
    return PendingFullBox(res, samples, ctx, batch, judge)


class PendingFullBox:
    """A started :func:`start_full_box_check`: :meth:`result` waits for the judged samples."""

    def __init__(
        self, res: FullBoxResult, samples: _Samples, ctx: tuple, batch: Batch, judge: tuple
    ):
        self._res, self._samples, self._ctx, self._batch = res, samples, ctx, batch
        self._judge = judge  # (R, C, gamma, rtol, ts) of _frozen
        self._ts = judge[4]

    def result(self) -> FullBoxResult:
        res = self._res
        smp = self._samples
        try:  # the extreme corners here (one BLAS thread, like a worker) while the draws run
            block = smp.rows(smp.n_draws, smp.n)
            corners = map_tasks(_judge_chunk, [(block, self._ctx, *self._judge)], 1)[0]
        except BaseException:
            self._batch.cancel()
            raise
        judged = [r for part in self._batch.results() for r in part] + corners
        worst_key = (-np.inf, -np.inf)
        worst_i = None
        for i, (norm, absc, ok) in enumerate(judged):
            where, vd = self._samples.where(i)
            s = FullBoxSample(where, vd, norm, absc, ok)
            res.samples.append(s)
            key = (absc if self._ts is not None else norm, absc)
            if key > worst_key:
                worst_key = key
                res.worst, worst_i = s, i
        if worst_i is not None:  # the worst system, built again (the same numbers)
            res.worst_A, res.worst_B, res.worst_K = _system(self._ctx, self._samples.spec(worst_i))
        return res
