"""Independent re-check of a gains certificate (seed 0 Lemma 1, Eqs. 29-31) without the solver.

Checks, each a row of the report:

1. ``hinf``: frozen-parameter closed loops A_i^j + B_i^j K_i at every scheduling vertex and every
   uncertainty vertex, H-infinity norm u_e -> z by Hamiltonian bisection
   (:mod:`lpv_sysid.synthesis.hinf_norm`) <= gamma;
2. ``hinf interior``: the same at random interior scheduling points with the interpolated model
   and gain (Eq. 21, Eq. 31), for the nominal model, for every uncertainty index j when all
   vertices have the same number M of uncertainty vertices (the j-th corners taken together,
   which is the same parameter theta for corner-enumerated polytopes), and for ``n_mix`` random
   corner mixes: A = sum_i alpha_i sum_j w_i^j A_i^j, B = sum_i alpha_i sum_j w_i^j B_i^j with
   Dirichlet weights; for a common input set (``model.common_input``) the weights are the product
   w_i^(a,b) = beta_i^a beta^b with one beta^b for all vertices, so B = sum_b beta^b B^b -- the
   frozen systems the common-B certificate claims (models.lpv module docstring);
2b. ``common B`` / ``product A`` (common input set only): B_i^(a,b) identical to B^b for all
   scheduling vertices i and A-corners a within 1e-12, and A_i^(a,b) independent of b -- the
   structure Lemma 1's interior argument needs; ``verify_files`` also checks that the structure
   is the one the certificate claims and that the B corners span every vertex's identified
   B interval and nominal value (``B hull``);
3. ``region``: closed-loop eigenvalues at all of the above points in the promised LMI region
   (the stability region when none is promised);
4. ``lmi``: when the certificate sidecar is present (sha256 checked), K_i == S_i H^-1 and the
   Eq. (30) LMIs re-evaluated with numpy eigenvalues from the stored X, S, H (after the stored
   diagonal congruence, which preserves inertia) hold at the file's gamma;
5. ``full-box *`` (optional, :func:`full_box_check`, ``verify_files(full_box=N)``): an *empirical*
   Monte Carlo check against the FULL identified uncertainty, which the certificate does not
   claim. Identification estimates ~43 elements per vertex; Lemma 1 is solved on the reduced
   polytope of Eq. (23) (influence reduction, ``p_max`` corner parameters widened to absorb the
   others to first order, :mod:`lpv_sysid.ident.uncertainty`), so the certificate covers that
   polytope, not the Eq. (22) box with every element in ``nominal +/- k std``. The check draws
   scheduling points v_d (the box corners, then uniform interior points) and, independently per
   scheduling vertex i, every identified element theta_i,l from its full interval (even samples
   uniform in the box, odd samples a random corner of it), forms A(v_d) = sum_i alpha_i A_i(theta_i),
   B(v_d) likewise (Eq. 21, multilinear alpha) and the interpolated gain K(v_d) (Eq. 31), and
   evaluates the frozen closed loop A + B K: spectral abscissa and H-inf norm u_e -> z
   (:func:`lpv_sysid.synthesis.hinf_norm.hinf_norm`). Two extreme corners per scheduling vertex are
   added: every element at the end of its interval that increases, to first order, (a) the
   closed-loop H-inf norm (analytic sensitivity of sigma_max at the peak frequency) and (b) the
   spectral abscissa (eigenvalue sensitivity y^H dA x / y^H x). The rows are ``ok`` only when
   every sample is stable with norm <= gamma; otherwise they are *advisory* (printed ``WARN``) and
   do not fail the report unless ``strict_full_box`` -- the certificate does not claim this set,
   so a miss is information for the flight-test engineer, not a broken certificate.

   Intervals (:func:`full_box_intervals`): identification (``ident.vertex.VertexResult.to_dict``)
   writes every element with its ``std``; only the kept corner parameters have ``lower < upper``
   (their interval *widened* by ``meta.uncertainty.inflation``, so it contains ``nominal +/- k std``),
   the dropped ones ``lower = upper = nominal``. The check uses the stored ``[lower, upper]`` where
   ``lower < upper`` and ``nominal +/- k std`` where the file stores ``lower = upper`` with
   ``std > 0``, with ``k`` = ``meta.k_sigma`` of the models file (raised to the Sidak value when
   ``meta.joint_alpha`` is set, as ``ident.uncertainty.build`` does), else 3 (the identification
   default); ``kept="ksigma"`` uses ``nominal +/- k std`` for the kept elements too (the Eq. 22
   box itself instead of the superset).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.lpv import PolytopicModel, common_input_deviation, multilinear_weights
from lpv_sysid.synthesis.hinf_lmi import certificate_margins
from lpv_sysid.synthesis.hinf_norm import hinf_norm
from lpv_sysid.synthesis.regions import Region
from lpv_sysid.synthesis.scaling import Scaling

log = logging.getLogger(__name__)


@dataclass
class CheckRow:
    check: str
    where: str
    value: float
    limit: float
    ok: bool
    note: str = ""
    advisory: bool = False      # empirical check the certificate does not claim: WARN, not FAIL

    @property
    def result(self) -> str:
        return "ok" if self.ok else ("WARN" if self.advisory else "FAIL")


@dataclass
class VerifyReport:
    rows: list = field(default_factory=list)
    full_box: Optional["FullBoxResult"] = None

    @property
    def passed(self) -> bool:
        """All rows ok; advisory rows (WARN) do not count."""
        return bool(self.rows) and all(r.ok or r.advisory for r in self.rows)

    @property
    def warnings(self) -> int:
        return sum(1 for r in self.rows if r.advisory and not r.ok)

    def add(self, *a, **kw) -> None:
        self.rows.append(CheckRow(*a, **kw))

    def worst(self, check: str) -> Optional[CheckRow]:
        rows = [r for r in self.rows if r.check == check]
        if not rows:
            return None
        bad = [r for r in rows if not r.ok]
        return bad[0] if bad else max(rows, key=lambda r: r.value if np.isfinite(r.value) else -np.inf)

    def table(self, max_rows: int = 40) -> str:
        """Failing rows first, then the worst passing row per check."""
        lines = [f"{'check':<14} {'where':<28} {'value':>12} {'limit':>12}  result"]
        shown = [r for r in self.rows if not r.ok][:max_rows]
        for chk in dict.fromkeys(r.check for r in self.rows):
            w = self.worst(chk)
            if w is not None and w.ok:
                shown.append(w)
        for r in shown:
            lines.append(f"{r.check:<14} {r.where:<28} {r.value:>12.6g} {r.limit:>12.6g}  "
                         f"{r.result}{('  ' + r.note) if r.note else ''}")
        n_bad = sum(not (r.ok or r.advisory) for r in self.rows)
        lines.append(f"{len(self.rows)} checks, {n_bad} failed"
                     + (f", {self.warnings} warnings (empirical, not certified)" if self.warnings else ""))
        return "\n".join(lines)


def _check_point(rep: VerifyReport, where: str, A: np.ndarray, B: np.ndarray, K: np.ndarray, R: np.ndarray,
                 C: np.ndarray, gamma: float, region: Optional[Region], rtol: float, ts: Optional[float]) -> None:
    Acl = A + B @ K
    eig = np.linalg.eigvals(Acl)
    if ts is not None:
        # discrete-time certificates are not produced by Lemma 1 (continuous); report stability only
        rho = float(np.max(np.abs(eig)))
        rep.add("stability", where, rho, 1.0, rho < 1.0)
    else:
        h = hinf_norm(Acl, B @ R, C)
        rep.add("hinf", where, h.value, gamma, bool(h.stable and h.lower <= gamma * (1 + rtol)),
                "" if h.stable else "closed loop unstable")
    if region is not None:
        ok = region.contains(eig, tol=1e-9 * max(1.0, float(np.max(np.abs(eig)))))
        k = int(np.argmin(ok)) if not np.all(ok) else int(np.argmax(eig.real))
        rep.add("region", where, float(eig[k].real), float("nan"), bool(np.all(ok)),
                f"eig {eig[k]:.4g}" + ("" if np.all(ok) else " outside region"))
    elif ts is None:
        mx = float(np.max(eig.real))
        rep.add("stability", where, mx, 0.0, mx < 0.0)


#: tolerance of the common-input structure check (B^b identical across vertices)
COMMON_B_TOL = 1e-12


def _mix_weights(model: PolytopicModel, rng: np.random.Generator) -> list:
    """Random corner weights w_i (M_i,) per vertex (product beta_i^a beta^b for a common input set)."""
    if model.common_input is None:
        return [rng.dirichlet(np.ones(len(lst))) for lst in model.systems]
    MB = model.common_input.M
    beta_b = rng.dirichlet(np.ones(MB))
    return [np.kron(rng.dirichlet(np.ones(len(lst) // MB)), beta_b) for lst in model.systems]


def verify_gains(model: PolytopicModel, K: np.ndarray, R: np.ndarray, C: np.ndarray, gamma: float,
                 region: Optional[Region] = None, n_random: int = 20, seed: int = 0, rtol: float = 1e-6,
                 certificate: Optional[dict] = None, k_rtol: float = 1e-6, n_mix: int = 3) -> VerifyReport:
    """Run the checks of the module docstring; ``certificate`` is the loaded sidecar (or None)."""
    rep = VerifyReport()
    K = np.asarray(K, dtype=float)
    R = np.asarray(R, dtype=float)
    C = np.asarray(C, dtype=float)
    if model.common_input is not None:
        dB, dA = common_input_deviation(model, model.common_input.M)
        rep.add("common B", "B_i^(a,b) vs B^b, all i, a", dB, COMMON_B_TOL, dB <= COMMON_B_TOL,
                "" if dB <= COMMON_B_TOL else "input matrix differs between vertices: interior not certified")
        rep.add("product A", "A_i^(a,b) vs A_i^(a,0)", dA, COMMON_B_TOL, dA <= COMMON_B_TOL,
                "" if dA <= COMMON_B_TOL else "systems are not the product A-corners x B-corners")
    for i, lst in enumerate(model.systems):
        for j, (A, B) in enumerate(lst):
            _check_point(rep, f"vertex {i} unc {j}", np.asarray(A), np.asarray(B), K[i], R, C, gamma, region,
                         rtol, model.ts)
    rng = np.random.default_rng(seed)
    Ms = {len(lst) for lst in model.systems}
    same_M = len(Ms) == 1
    As_all = [np.array([np.asarray(a, dtype=float) for a, _ in lst]) for lst in model.systems]
    Bs_all = [np.array([np.asarray(b, dtype=float) for _, b in lst]) for lst in model.systems]
    for k in range(n_random):
        vd = model.vmin + rng.random(model.vmin.size) * (model.vmax - model.vmin)
        alpha, _ = multilinear_weights(vd, model.vmin, model.vmax)
        Kv = np.tensordot(alpha, K, axes=1)
        cases = [("nom", np.tensordot(alpha, model.A, axes=1), np.tensordot(alpha, model.B, axes=1))]
        if same_M and next(iter(Ms)) > 1:
            for j in range(next(iter(Ms))):
                cases.append((f"unc {j}", sum(a * As_all[i][j] for i, a in enumerate(alpha)),
                              sum(a * Bs_all[i][j] for i, a in enumerate(alpha))))
        if max(Ms) > 1:
            for r in range(n_mix):
                w = _mix_weights(model, rng)
                cases.append((f"mix {r}",
                              sum(a * np.tensordot(w[i], As_all[i], axes=1) for i, a in enumerate(alpha)),
                              sum(a * np.tensordot(w[i], Bs_all[i], axes=1) for i, a in enumerate(alpha))))
        for name, A, B in cases:
            _check_point(rep, f"interior {k} {name}", A, B, Kv, R, C, gamma, region, rtol, model.ts)
    for r in rep.rows:
        if r.check == "hinf" and r.where.startswith("interior"):
            r.check = "hinf interior"
    if certificate is not None:
        _check_lmi(rep, model, K, R, C, gamma, certificate, k_rtol)
    return rep


def _check_input_claim(rep: VerifyReport, model: PolytopicModel, claim: Optional[dict], raw: dict) -> None:
    """The certificate's input_structure vs the rebuilt polytope, and the B hull's coverage of the
    models file (read from the raw YAML, not through models.lpv.input_hull)."""
    if not isinstance(claim, dict):
        return
    st = model.input_structure
    same = all(claim.get(k) == st.get(k) for k in ("B", "M_A", "M_B"))
    rep.add("structure", f"B {claim.get('B')} M_B {claim.get('M_B')}", 0.0 if same else 1.0, 0.0, bool(same),
            "" if same else f"rebuilt polytope is B {st['B']}, M_A {st['M_A']}, M_B {st['M_B']}")
    if st["B"] != "common" or not same:
        if st["B"] == "per_vertex":
            rep.add("coverage", "scheduling box", 0.0, 0.0, True,
                    "per-vertex B: Lemma 1 certifies the vertices; interior only spot-checked")
        return
    corners = np.asarray(model.common_input.corners, dtype=float)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    worst = 0.0
    for v in raw.get("vertices", []):
        Bv = np.asarray(v["B"], dtype=float)
        worst = max(worst, float(np.max(np.maximum(lo - Bv, Bv - hi))))
        for e in v.get("uncertain") or []:
            if e.get("matrix") == "B":
                r, c = int(e["row"]), int(e["col"])
                worst = max(worst, lo[r, c] - float(e["lower"]), float(e["upper"]) - hi[r, c])
    tol = 1e-12 * max(1.0, float(np.max(np.abs(corners))))
    exact = model.common_input.method in ("box", "hybrid")
    ok = worst <= tol or not exact
    note = "" if worst <= tol else ("identified B interval outside the common B corners" if exact else
                                    "influence reduction of B: first-order, not a set containment")
    rep.add("B hull", "B^b span all vertex B intervals", max(worst, 0.0), tol, bool(ok), note)


def _check_lmi(rep: VerifyReport, model: PolytopicModel, K: np.ndarray, R: np.ndarray, C: np.ndarray, gamma: float,
               cert: dict, k_rtol: float) -> None:
    X, S, H = cert["X_list"], np.asarray(cert["S"]), np.asarray(cert["H"])
    sc = Scaling(t=np.asarray(cert["t"], float), s_u=np.asarray(cert["s_u"], float))
    if len(X) != model.n_vertices or any(len(X[i]) != len(model.systems[i]) for i in range(model.n_vertices)):
        rep.add("lmi", "shapes", float("nan"), float("nan"), False,
                "certificate X does not match the models' uncertainty vertices")
        return
    for i in range(model.n_vertices):
        try:
            K_cert = np.linalg.solve(H.T, S[i].T).T
        except np.linalg.LinAlgError:
            rep.add("K = S H^-1", f"vertex {i}", float("inf"), k_rtol, False, "H singular")
            continue
        # compare in the scaled coordinates (relative to the gain's own magnitude there)
        Ks, Kc = K[i] * sc.t[None, :] / sc.s_u[:, None], K_cert * sc.t[None, :] / sc.s_u[:, None]
        err = float(np.max(np.abs(Ks - Kc)) / max(np.max(np.abs(Kc)), 1e-300))
        rep.add("K = S H^-1", f"vertex {i}", err, k_rtol, err <= k_rtol)
    for key in ("R", "C"):
        if key in cert:
            ref = R if key == "R" else C
            same = np.shape(cert[key]) == np.shape(ref) and np.allclose(cert[key], ref, rtol=1e-12, atol=0)
            rep.add("lmi data", key, 0.0 if same else 1.0, 0.0, bool(same),
                    "" if same else f"{key} differs from the one the certificate was computed with")
    gam, margin = certificate_margins(model, R, C, X, S, H, sc, gamma=gamma)
    rep.add("lmi gamma", "Eq. (30) all i,j", gam, gamma, gam <= gamma)
    rep.add("lmi margin", "Eq. (30) all i,j", margin, 0.0, margin > 0.0,
            "min(-lambda_max(LMI), lambda_min(X))")


#: relative tolerance of the recomputed feedforward matrices (YAML keeps ~16 digits)
FF_RTOL = 1e-8


def check_feedforward(rep: VerifyReport, model: PolytopicModel, F_ff: np.ndarray, layout: dict,
                      F_jerk: Optional[np.ndarray] = None, rtol: float = FF_RTOL) -> None:
    """Recompute F_i (and F_jerk,i) from the nominal vertex models (synthesis/feedforward.py) and
    compare with the stored ones; also the defining property: A_i dx_ff + B_i du_ff has the
    accelerated rows = a and the held rows = 0 for a = each unit vector (independent of how F was
    computed)."""
    from lpv_sysid.synthesis.feedforward import (FeedforwardLayout, feedforward_matrix, feedforward_residual,
                                                 jerk_matrix)

    try:
        lay = FeedforwardLayout.from_dict(layout)
        free, acc, held = lay.indices(model.state_names)
    except ConfigError as exc:
        rep.add("feedforward", "layout", 1.0, 0.0, False, str(exc))
        return
    F_ff = np.asarray(F_ff, dtype=float)
    want = (model.n_vertices, len(free) + model.n_u, len(acc))
    if F_ff.shape != want:
        rep.add("feedforward", "F_ff shape", 1.0, 0.0, False, f"shape {F_ff.shape}, expected {want}")
        return
    for i in range(model.n_vertices):
        try:
            F = feedforward_matrix(model.A[i], model.B[i], model.state_names, lay, where=f"vertex {i}")
        except ConfigError as exc:
            rep.add("feedforward", f"vertex {i}", float("inf"), rtol, False, str(exc))
            continue
        err = float(np.max(np.abs(F_ff[i] - F)) / max(1.0, float(np.max(np.abs(F)))))
        rep.add("feedforward", f"vertex {i} F_ff vs recomputed", err, rtol, err <= rtol,
                "" if err <= rtol else "stored F_ff differs from the one of the nominal model")
        scale = max(1.0, float(np.max(np.abs(model.A[i]))), float(np.max(np.abs(model.B[i]))))
        res = max(float(np.max(np.abs(feedforward_residual(model.A[i], model.B[i], F_ff[i], free, acc, e)[acc + held])))
                  for e in np.eye(len(acc)))
        ok = res <= 1e-9 * scale
        rep.add("ff residual", f"vertex {i} A dx_ff + B du_ff - a", res, 1e-9 * scale, ok,
                "" if ok else "stored F_ff does not produce the requested acceleration")
        if lay.has_jerk:
            if F_jerk is None:
                rep.add("ff jerk", f"vertex {i}", 1.0, 0.0, False, "layout declares the jerk term, F_jerk missing")
                continue
            try:
                Fj = jerk_matrix(model.A[i], model.B[i], model.state_names, F, lay, where=f"vertex {i}")
            except ConfigError as exc:
                rep.add("ff jerk", f"vertex {i}", float("inf"), rtol, False, str(exc))
                continue
            Fj_s = np.asarray(F_jerk[i], dtype=float)
            if Fj_s.shape != Fj.shape:
                rep.add("ff jerk", f"vertex {i} F_jerk shape", 1.0, 0.0, False, f"{Fj_s.shape} != {Fj.shape}")
                continue
            err = float(np.max(np.abs(Fj_s - Fj)) / max(1.0, float(np.max(np.abs(Fj)))))
            rep.add("ff jerk", f"vertex {i} F_jerk vs recomputed", err, rtol, err <= rtol,
                    "" if err <= rtol else "stored F_jerk differs from the one of the nominal model")


# --------------------------------------------------------------------------- full identified box
#: half-width multiplier of Eq. (22) when the models file records none (ident default k_sigma)
DEFAULT_K_SIGMA = 3.0


@dataclass(frozen=True)
class ElementBox:
    """Full identified intervals of one scheduling vertex (seed 0 Eq. 22): element l is
    ``A[row, col]`` (is_a) or ``B[row, col]`` in ``[lower_l, upper_l]``."""

    is_a: np.ndarray       # (p,) bool
    row: np.ndarray        # (p,) int
    col: np.ndarray        # (p,) int
    nominal: np.ndarray    # (p,)
    lower: np.ndarray      # (p,)
    upper: np.ndarray      # (p,)
    source: tuple          # (p,) "stored" | "k*std" | "fixed"

    def apply(self, A: np.ndarray, B: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        A, B = A.copy(), B.copy()
        A[self.row[self.is_a], self.col[self.is_a]] = theta[self.is_a]
        B[self.row[~self.is_a], self.col[~self.is_a]] = theta[~self.is_a]
        return A, B


def full_box_k(raw: dict, k_sigma: Optional[float] = None) -> tuple[float, str]:
    """k of Eq. (22): the argument, else ``meta.k_sigma`` of the models file, else 3. Returns (k, where)."""
    if k_sigma is not None:
        k, where = float(k_sigma), "given"
    else:
        meta = raw.get("meta") if isinstance(raw.get("meta"), dict) else {}
        k, where = (float(meta["k_sigma"]), "models meta.k_sigma") if meta.get("k_sigma") is not None \
            else (DEFAULT_K_SIGMA, "default (models file records no k_sigma)")
    if not (np.isfinite(k) and k > 0):
        raise ConfigError(f"full-box check: k_sigma must be > 0, got {k!r}")
    return k, where


def full_box_intervals(raw: dict, k_sigma: Optional[float] = None, kept: str = "stored") -> tuple[list, float, str]:
    """One :class:`ElementBox` per vertex (box order) from the raw ``vertex_models.yaml`` mapping.

    Rule (module docstring, item 5): stored ``[lower, upper]`` where ``lower < upper`` (``kept ==
    "stored"``), ``nominal +/- k std`` where ``lower == upper`` and ``std > 0`` (and for every
    element with ``kept == "ksigma"``), fixed at ``nominal`` when ``std == 0`` and ``lower == upper``.
    With ``meta.joint_alpha`` k is raised to the Sidak value per vertex (ident.uncertainty.build).
    """
    if kept not in ("stored", "ksigma"):
        raise ConfigError(f"full-box check: kept must be 'stored' or 'ksigma', got {kept!r}")
    k0, where = full_box_k(raw, k_sigma)
    meta = raw.get("meta") if isinstance(raw.get("meta"), dict) else {}
    alpha = meta.get("joint_alpha") if k_sigma is None else None
    out = []
    for i, v in enumerate(raw.get("vertices") or []):
        els = v.get("uncertain") or []
        k = k0
        if alpha is not None and els:
            from lpv_sysid.ident.uncertainty import sidak_k

            k = max(k0, sidak_k(len(els), float(alpha)))
        cols = {key: [] for key in ("is_a", "row", "col", "nominal", "lower", "upper", "source")}
        for e in els:
            try:
                nom, std = float(e["nominal"]), float(e.get("std", 0.0))
                lo, hi = float(e["lower"]), float(e["upper"])
                isa, r, c = e["matrix"] == "A", int(e["row"]), int(e["col"])
            except (KeyError, TypeError, ValueError) as exc:
                raise ConfigError(f"models: vertices[{i}].uncertain: bad entry {e!r} ({exc})") from None
            if not all(np.isfinite([nom, std, lo, hi])) or std < 0:
                raise ConfigError(f"models: vertices[{i}].uncertain {e.get('matrix')}[{r},{c}]: "
                                  "non-finite bounds or negative std")
            if hi > lo and kept == "stored":
                src = "stored"
            elif std > 0:
                lo, hi, src = nom - k * std, nom + k * std, "k*std"
            else:
                src = "fixed" if hi == lo else "stored"
            for key, val in zip(cols, (isa, r, c, nom, lo, hi, src)):
                cols[key].append(val)
        out.append(ElementBox(np.array(cols["is_a"], dtype=bool), np.array(cols["row"], dtype=int),
                              np.array(cols["col"], dtype=int), np.array(cols["nominal"], dtype=float),
                              np.array(cols["lower"], dtype=float), np.array(cols["upper"], dtype=float),
                              tuple(cols["source"])))
    return out, k0, where


@dataclass
class FullBoxSample:
    where: str               # "corner 3 uniform", "interior 17 corner-draw", "vertex 2 worst-norm corner"
    v_d: np.ndarray
    norm: float              # H-inf norm u_e -> z (inf when unstable; nan in discrete time)
    abscissa: float          # max Re eig (continuous) or spectral radius - 1 (discrete)
    ok: bool


@dataclass
class FullBoxResult:
    """Outcome of :func:`full_box_check` (empirical, not certified)."""

    samples: list
    gamma: float
    k_sigma: float
    k_source: str
    seed: int
    n_elements: list         # identified elements per vertex
    n_stored: int            # elements using the stored [lower, upper] (all vertices)
    n_ksigma: int            # elements using nominal +/- k std
    worst: Optional[FullBoxSample] = None
    worst_A: Optional[np.ndarray] = None      # frozen closed-loop data of the worst sample
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
        return {"samples": self.n, "seed": int(self.seed), "gamma": float(self.gamma),
                "k_sigma": float(self.k_sigma), "k_sigma_source": self.k_source,
                "elements_per_vertex": [int(x) for x in self.n_elements],
                "intervals_stored": int(self.n_stored), "intervals_k_std": int(self.n_ksigma),
                "worst_norm": float(w.norm) if w is not None else float("nan"),
                "worst_where": w.where if w is not None else "",
                "worst_v_d": [float(x) for x in w.v_d] if w is not None else [],
                "fraction_ok": float(self.fraction_ok), "all_stable": bool(self.all_stable),
                "max_abscissa": float(self.max_abscissa), "passed": bool(self.passed),
                "note": "empirical Monte Carlo over the full identified box; not claimed by the certificate"}


def _frozen(A: np.ndarray, B: np.ndarray, K: np.ndarray, R: np.ndarray, C: np.ndarray, gamma: float,
            rtol: float, ts: Optional[float]) -> tuple[float, float, bool]:
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


def _worst_corners(A: np.ndarray, B: np.ndarray, K: np.ndarray, R: np.ndarray, C: np.ndarray,
                   box: ElementBox, ts: Optional[float]) -> list:
    """First-order worst corners of the element box at one scheduling vertex: every element at the
    end of its interval that increases (a) the H-inf norm and (b) the spectral abscissa, to first
    order at the box centre (:func:`element_sensitivities`)."""
    if box.is_a.size == 0:
        return []
    th0 = 0.5 * (box.lower + box.upper)
    return [(name, np.where(g > 0, box.upper, box.lower))
            for name, g in element_sensitivities(A, B, K, R, C, box, th0, ts)]


def element_sensitivities(A: np.ndarray, B: np.ndarray, K: np.ndarray, R: np.ndarray, C: np.ndarray,
                          box: ElementBox, theta: np.ndarray, ts: Optional[float] = None) -> list:
    """[("worst-norm corner", d||G||_inf/d theta), ("worst-abscissa corner", d max Re lambda/d theta)]
    of the frozen closed loop at ``theta`` (the norm entry only when stable, continuous time).

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
        p = u.conj() @ C @ Rz                     # (n,)
        q = Rz @ (B0 @ R) @ v                      # (n,)
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
    """Peak frequency of sigma_max near the bisection's w0 (its bracket ends at a midpoint, O(dw) off
    the maximiser; the envelope-theorem gradient needs the maximiser). scipy bounded Brent."""
    from scipy.optimize import minimize_scalar

    from lpv_sysid.synthesis.hinf_norm import sigma_max

    if w0 <= 0.0:
        return 0.0
    r = minimize_scalar(lambda w: -sigma_max(A, B, C, w), bounds=(0.8 * w0, 1.25 * w0), method="bounded",
                        options={"xatol": 1e-10 * w0})
    return float(r.x) if -r.fun >= sigma_max(A, B, C, w0) else w0


def _eig_lr(M: np.ndarray):
    from scipy.linalg import eig

    w, vl, vr = eig(M, left=True, right=True)
    return w, vl, vr


def full_box_check(model: PolytopicModel, K: np.ndarray, R: np.ndarray, C: np.ndarray, gamma: float,
                   boxes: list, n: int = 200, seed: int = 0, rtol: float = 1e-6, extremes: bool = True,
                   k_sigma: float = DEFAULT_K_SIGMA, k_source: str = "") -> FullBoxResult:
    """Monte Carlo over the full identified box (module docstring, item 5); empirical only.

    ``boxes``: :func:`full_box_intervals` (one per vertex, box order). Samples: the 2^p scheduling
    corners first (when n allows), then uniform interior v_d; per sample and per vertex the
    elements are drawn independently, uniform in their interval (even samples) or at a random
    corner of it (odd samples). ``extremes`` adds the two first-order worst corners per scheduling
    vertex (:func:`_worst_corners`). Seeded: same inputs and seed -> same samples.
    """
    if len(boxes) != model.n_vertices:
        raise ConfigError(f"full-box check: {len(boxes)} element boxes for {model.n_vertices} vertices")
    for i, b in enumerate(boxes):
        n_col = np.where(b.is_a, model.n_x, model.n_u)
        if b.row.size and (np.any(b.row < 0) or np.any(b.row >= model.n_x) or np.any(b.col < 0)
                           or np.any(b.col >= n_col)):
            raise ConfigError(f"full-box check: vertex {i}: uncertain element outside A ({model.n_x}x{model.n_x}) "
                              f"/ B ({model.n_x}x{model.n_u})")
        if np.any(b.lower > b.upper) or not np.all(np.isfinite(np.r_[b.lower, b.upper])):
            raise ConfigError(f"full-box check: vertex {i}: need finite lower <= upper")
    K = np.asarray(K, dtype=float)
    R = np.asarray(R, dtype=float)
    C = np.asarray(C, dtype=float)
    rng = np.random.default_rng(seed)
    verts = model.vertices
    res = FullBoxResult([], float(gamma), float(k_sigma), k_source, int(seed), [b.is_a.size for b in boxes],
                        sum(s == "stored" for b in boxes for s in b.source),
                        sum(s == "k*std" for b in boxes for s in b.source))
    worst_key = (-np.inf, -np.inf)

    def record(where, vd, A, B, Kv):
        nonlocal worst_key
        norm, absc, ok = _frozen(A, B, Kv, R, C, gamma, rtol, model.ts)
        s = FullBoxSample(where, np.asarray(vd, dtype=float), norm, absc, ok)
        res.samples.append(s)
        key = (absc if model.ts is not None else norm, absc)
        if key > worst_key:
            worst_key = key
            res.worst, res.worst_A, res.worst_B, res.worst_K = s, A, B, Kv

    for k in range(max(0, int(n))):
        if k < len(verts):
            vd, tag = verts[k], f"corner {k}"
        else:
            vd, tag = model.vmin + rng.random(model.vmin.size) * (model.vmax - model.vmin), f"interior {k}"
        alpha, _ = multilinear_weights(vd, model.vmin, model.vmax)
        corner_draw = k % 2 == 1
        A = np.zeros_like(model.A[0])
        B = np.zeros_like(model.B[0])
        for i, a in enumerate(alpha):
            b = boxes[i]
            if corner_draw:
                th = np.where(rng.random(b.lower.size) < 0.5, b.lower, b.upper)
            else:
                th = b.lower + rng.random(b.lower.size) * (b.upper - b.lower)
            if a == 0.0:
                continue
            Ai, Bi = b.apply(model.A[i], model.B[i], th)
            A += a * Ai
            B += a * Bi
        record(f"{tag} {'corner-draw' if corner_draw else 'uniform'}", vd, A, B, np.tensordot(alpha, K, axes=1))
    if extremes and n > 0:
        for i, vd in enumerate(verts):
            for name, th in _worst_corners(model.A[i], model.B[i], K[i], R, C, boxes[i], model.ts):
                Ai, Bi = boxes[i].apply(model.A[i], model.B[i], th)
                record(f"vertex {i} {name}", vd, Ai, Bi, K[i])
    return res


def add_full_box_rows(rep: VerifyReport, res: FullBoxResult, strict: bool = False) -> None:
    """Rows ``full-box hinf`` / ``full-box frac`` / ``full-box stab``: ``ok`` only when every sample
    passes; otherwise advisory (WARN) unless ``strict``."""
    rep.full_box = res
    adv = not strict
    w = res.worst
    vd = "[" + ", ".join(f"{x:.3g}" for x in w.v_d) + "]" if w is not None else "-"
    tag = f"empirical, {res.n} samples, k={res.k_sigma:g}; not certified"
    if w is not None and not np.isnan(w.norm):
        rep.add("full-box hinf", f"worst v_d {vd}", w.norm, res.gamma, res.passed,
                f"{w.where}; {tag}", advisory=adv)
    n_ok = sum(s.ok for s in res.samples)
    rep.add("full-box frac", f"{n_ok}/{res.n} samples ok", res.fraction_ok, 1.0, res.passed,
            "fraction with norm <= gamma and stable", advisory=adv)
    n_unst = sum(s.abscissa >= 0 for s in res.samples)
    rep.add("full-box stab", "max Re eig" if res.worst is None or not np.isnan(res.worst.norm)
            else "max |eig| - 1", res.max_abscissa, 0.0, res.all_stable,
            "" if res.all_stable else f"{n_unst} unstable samples", advisory=adv)


def verify_files(gains_path: Path | str, models_path: Path | str, n_random: int = 20, seed: int = 0,
                 uncertainty: Optional[dict] = None, velocity_index=None, full_box: int = 0,
                 strict_full_box: bool = False, k_sigma: Optional[float] = None,
                 full_box_kept: str = "stored") -> VerifyReport:
    """Load gains.yaml (+ sidecar) and vertex_models.yaml and run :func:`verify_gains`.

    Also checks names, box, equilibria and the models_sha256 of the certificate. ``full_box`` > 0
    adds the empirical Monte Carlo check over the full identified box (module docstring item 5,
    :func:`full_box_check` with ``seed``); its rows are advisory (WARN, ``passed`` unaffected)
    unless ``strict_full_box``. ``k_sigma`` overrides the models file's ``meta.k_sigma``.
    """
    from lpv_sysid.synthesis.files import Gains, load_certificate_npz, load_models, sha256_file
    from lpv_sysid.synthesis.hinf_lmi import performance_matrix

    gains = Gains.load(gains_path)
    cert = gains.certificate
    claim = cert.get("input_structure")
    if uncertainty is not None:
        unc_cfg = uncertainty
    else:
        # rebuild the polytope the certificate was solved for; certificates without an
        # input_structure entry predate the common-B option and are per-vertex
        unc_raw = cert.get("uncertainty") or {}
        if not isinstance(unc_raw, dict):
            raise ConfigError(f"{gains_path}: certificate.uncertainty must be a mapping, got {unc_raw!r}")
        unc_cfg = dict(unc_raw)
        unc_cfg["common_b"] = isinstance(claim, dict) and claim.get("B") == "common"
    model, raw = load_models(models_path, unc_cfg)
    rep = VerifyReport()
    sha = sha256_file(models_path)
    rep.add("models hash", Path(models_path).name, 0.0 if sha == cert.get("models_sha256") else 1.0, 0.0,
            sha == cert.get("models_sha256"), "" if sha == cert.get("models_sha256") else
            "models file differs from the one the gains were synthesised for")
    same_names = (gains.state_names == model.state_names and gains.input_names == model.input_names
                  and gains.scheduling_names == model.scheduling_names)
    rep.add("names", "states/inputs/scheduling", 0.0 if same_names else 1.0, 0.0, same_names)
    same_box = np.allclose(gains.vmin, model.vmin) and np.allclose(gains.vmax, model.vmax)
    rep.add("box", "scheduling min/max", 0.0 if same_box else 1.0, 0.0, bool(same_box))
    eq_err = float(max(np.max(np.abs(gains.x0 - model.x0)), np.max(np.abs(gains.u0 - model.u0))))
    rep.add("equilibria", "x0/u0 vs models", eq_err, 1e-9, eq_err <= 1e-9)
    if not (same_names and same_box):
        return rep
    _check_input_claim(rep, model, claim, raw)
    if gains.F_ff is not None:
        check_feedforward(rep, model, gains.F_ff, gains.feedforward, gains.F_jerk)
    region = Region.from_dict(cert.get("region")) if cert.get("region") else None
    sidecar = None
    side = cert.get("sidecar")
    if isinstance(side, dict) and side.get("file"):
        p = Path(gains_path).parent / str(side["file"])
        if not os.path.lexists(p):
            rep.add("sidecar", p.name, 1.0, 0.0, False, "certificate sidecar missing")
        else:
            # present but unreadable (not a regular file, empty, truncated, corrupt): a damaged
            # input, ConfigError (exit 2), not a failed verification; readable but altered: FAIL
            load_certificate_npz(p)
            ok = sha256_file(p) == side.get("sha256")
            rep.add("sidecar", p.name, 0.0 if ok else 1.0, 0.0, ok, "" if ok else "sha256 mismatch")
            if ok:
                sidecar = load_certificate_npz(p)
    if velocity_index is None and cert.get("velocity_states"):
        try:
            velocity_index = tuple(model.state_names.index(nm) for nm in cert["velocity_states"])
        except ValueError:
            rep.add("velocity", "certificate.velocity_states", 1.0, 0.0, False, "names not among the states")
            return rep
    if velocity_index is None:
        names = ("u", "v", "w")
        velocity_index = (tuple(model.state_names.index(n) for n in names)
                          if all(n in model.state_names for n in names) else (2, 3, 4))
    C = performance_matrix(gains.Q, model.n_x, velocity_index)
    sub = verify_gains(model, gains.K, gains.R, C, gains.gamma, region, n_random, seed, certificate=sidecar)
    rep.rows.extend(sub.rows)
    ga = cert.get("gamma_achieved")
    if ga is not None:
        worst = max((r.value for r in rep.rows if r.check.startswith("hinf")), default=float("nan"))
        rep.add("gamma claim", "certificate.gamma_achieved", worst, float(ga) * (1 + 1e-3) + 1e-12,
                bool(worst <= float(ga) * (1 + 1e-3) + 1e-12),
                "worst independent H-inf norm vs the claimed gamma_achieved")
    if full_box > 0:
        boxes, k, k_src = full_box_intervals(raw, k_sigma, full_box_kept)
        res = full_box_check(model, gains.K, gains.R, C, gains.gamma, boxes, n=full_box, seed=seed,
                             k_sigma=k, k_source=k_src)
        add_full_box_rows(rep, res, strict=strict_full_box)
    return rep
