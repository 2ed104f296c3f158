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
4b. element-box certificates (``certificate.certified_set.kind: full_identified_box``, sidecar
   ``lmi_form`` 1-3, :mod:`lpv_sysid.synthesis.robust_lmi`), checked without the synthesis code:
   ``box claim`` -- the certified box (sidecar ``box_*``) contains every element interval of the
   models file read here from the raw YAML (:func:`full_box_intervals`, the stored [lower, upper]
   or nominal +/- k std) and its nominal A_i, B_i (elements outside the box equal the file's);
   ``box lmi`` -- the robust LMI re-assembled here in its *uncompressed* Schur form
   [Phi + L T L^T, cal_R^T; cal_R, -T] < 0 (the solver used the compressed harmonic-sum form)
   from the stored X, S, H and multipliers t_l, at every vertex (and, for the rate form, at every
   sign pattern of dv_d/dt from the stored rate bound, the exact condition the solver's W
   relaxation implies); ``small gain`` -- independent of X and H: the KYP-equivalent
   frequency-domain condition at every vertex, ||[C/gamma; T^-1/2 R~ [I; K_i]] (sI - A_cl)^-1
   [B R, L T^1/2] + [0 0; T^-1/2 R~ [0; R] 0]||_inf < 1 (scaled small gain: the vertex bound for
   every delta in the box, Hamiltonian H-inf norm with feedthrough); ``runtime set`` -- every
   system the flight runtime re-checks (sidecar A_sys, B_sys) lies in the certified box;
   ``scheduling`` -- the claimed variation (frozen / arbitrary / rate-bounded) matches the stored
   LMI form and, for rate bounds, the design envelope.
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
   do not fail the report unless ``strict_full_box`` -- a reduced-polytope certificate does not
   claim this set, so a miss is information for the flight-test engineer. For a full-box
   certificate (item 4b) the Monte Carlo is an empirical cross-check of the claim: a miss fails.

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
    advisory: bool = False  # empirical check the certificate does not claim: WARN, not FAIL

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
        return (
            bad[0]
            if bad
            else max(rows, key=lambda r: r.value if np.isfinite(r.value) else -np.inf)
        )

    def table(self, max_rows: int = 40) -> str:
        """Failing rows first, then the worst passing row per check."""
        lines = [f"{'check':<14} {'where':<28} {'value':>12} {'limit':>12}  result"]
        shown = [r for r in self.rows if not r.ok][:max_rows]
        for chk in dict.fromkeys(r.check for r in self.rows):
            w = self.worst(chk)
            if w is not None and w.ok:
                shown.append(w)
        for r in shown:
            lines.append(
                f"{r.check:<14} {r.where:<28} {r.value:>12.6g} {r.limit:>12.6g}  "
                f"{r.result}{('  ' + r.note) if r.note else ''}"
            )
        n_bad = sum(not (r.ok or r.advisory) for r in self.rows)
        lines.append(
            f"{len(self.rows)} checks, {n_bad} failed"
            + (f", {self.warnings} warnings (empirical, not certified)" if self.warnings else "")
        )
        return "\n".join(lines)


def _check_point(
    rep: VerifyReport,
    where: str,
    A: np.ndarray,
    B: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    region: Optional[Region],
    rtol: float,
    ts: Optional[float],
) -> None:
    Acl = A + B @ K
    eig = np.linalg.eigvals(Acl)
    if ts is not None:
        # discrete-time certificates are not produced by Lemma 1 (continuous); report stability only
        rho = float(np.max(np.abs(eig)))
        rep.add("stability", where, rho, 1.0, rho < 1.0)
    else:
        h = hinf_norm(Acl, B @ R, C)
        rep.add(
            "hinf",
            where,
            h.value,
            gamma,
            bool(h.stable and h.lower <= gamma * (1 + rtol)),
            "" if h.stable else "closed loop unstable",
        )
    if region is not None:
        ok = region.contains(eig, tol=1e-9 * max(1.0, float(np.max(np.abs(eig)))))
        k = int(np.argmin(ok)) if not np.all(ok) else int(np.argmax(eig.real))
        rep.add(
            "region",
            where,
            float(eig[k].real),
            float("nan"),
            bool(np.all(ok)),
            f"eig {eig[k]:.4g}" + ("" if np.all(ok) else " outside region"),
        )
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


def verify_gains(
    model: PolytopicModel,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    region: Optional[Region] = None,
    n_random: int = 20,
    seed: int = 0,
    rtol: float = 1e-6,
    certificate: Optional[dict] = None,
    k_rtol: float = 1e-6,
    n_mix: int = 3,
) -> VerifyReport:
    """Run the checks of the module docstring; ``certificate`` is the loaded sidecar (or None)."""
    rep = VerifyReport()
    K = np.asarray(K, dtype=float)
    R = np.asarray(R, dtype=float)
    C = np.asarray(C, dtype=float)
    if model.common_input is not None:
        dB, dA = common_input_deviation(model, model.common_input.M)
        rep.add(
            "common B",
            "B_i^(a,b) vs B^b, all i, a",
            dB,
            COMMON_B_TOL,
            dB <= COMMON_B_TOL,
            ""
            if dB <= COMMON_B_TOL
            else "input matrix differs between vertices: interior not certified",
        )
        rep.add(
            "product A",
            "A_i^(a,b) vs A_i^(a,0)",
            dA,
            COMMON_B_TOL,
            dA <= COMMON_B_TOL,
            "" if dA <= COMMON_B_TOL else "systems are not the product A-corners x B-corners",
        )
    for i, lst in enumerate(model.systems):
        for j, (A, B) in enumerate(lst):
            _check_point(
                rep,
                f"vertex {i} unc {j}",
                np.asarray(A),
                np.asarray(B),
                K[i],
                R,
                C,
                gamma,
                region,
                rtol,
                model.ts,
            )
    rng = np.random.default_rng(seed)
    Ms = {len(lst) for lst in model.systems}
    same_M = len(Ms) == 1
    As_all = [np.array([np.asarray(a, dtype=float) for a, _ in lst]) for lst in model.systems]
    Bs_all = [np.array([np.asarray(b, dtype=float) for _, b in lst]) for lst in model.systems]
    for k in range(n_random):
        vd = model.vmin + rng.random(model.vmin.size) * (model.vmax - model.vmin)
        alpha, _ = multilinear_weights(vd, model.vmin, model.vmax)
        Kv = np.tensordot(alpha, K, axes=1)
        cases = [
            ("nom", np.tensordot(alpha, model.A, axes=1), np.tensordot(alpha, model.B, axes=1))
        ]
        if same_M and next(iter(Ms)) > 1:
            for j in range(next(iter(Ms))):
                cases.append(
                    (
                        f"unc {j}",
                        sum(a * As_all[i][j] for i, a in enumerate(alpha)),
                        sum(a * Bs_all[i][j] for i, a in enumerate(alpha)),
                    )
                )
        if max(Ms) > 1:
            for r in range(n_mix):
                w = _mix_weights(model, rng)
                cases.append(
                    (
                        f"mix {r}",
                        sum(
                            a * np.tensordot(w[i], As_all[i], axes=1) for i, a in enumerate(alpha)
                        ),
                        sum(
                            a * np.tensordot(w[i], Bs_all[i], axes=1) for i, a in enumerate(alpha)
                        ),
                    )
                )
        for name, A, B in cases:
            _check_point(
                rep, f"interior {k} {name}", A, B, Kv, R, C, gamma, region, rtol, model.ts
            )
    for r in rep.rows:
        if r.check == "hinf" and r.where.startswith("interior"):
            r.check = "hinf interior"
    if certificate is not None:
        form = int(np.asarray(certificate.get("lmi_form", 0))) if "lmi_form" in certificate else 0
        if model.box is not None or form in (1, 3):
            check_box_lmi(rep, model, K, R, C, gamma, certificate, k_rtol)
        else:
            _check_lmi(rep, model, K, R, C, gamma, certificate, k_rtol)
    return rep


def _check_input_claim(
    rep: VerifyReport, model: PolytopicModel, claim: Optional[dict], raw: dict
) -> None:
    """The certificate's input_structure vs the rebuilt polytope, and the B hull's coverage of the
    models file (read from the raw YAML, not through models.lpv.input_hull)."""
    if not isinstance(claim, dict):
        return
    st = model.input_structure
    same = all(claim.get(k) == st.get(k) for k in ("B", "M_A", "M_B"))
    rep.add(
        "structure",
        f"B {claim.get('B')} M_B {claim.get('M_B')}",
        0.0 if same else 1.0,
        0.0,
        bool(same),
        "" if same else f"rebuilt polytope is B {st['B']}, M_A {st['M_A']}, M_B {st['M_B']}",
    )
    if model.box is not None:
        return  # the element box's claim is checked against the raw file by check_box_claim
    if st["B"] != "common" or not same:
        if st["B"] == "per_vertex":
            rep.add(
                "coverage",
                "scheduling box",
                0.0,
                0.0,
                True,
                "per-vertex B: Lemma 1 certifies the vertices; interior only spot-checked",
            )
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
    note = (
        ""
        if worst <= tol
        else (
            "identified B interval outside the common B corners"
            if exact
            else "influence reduction of B: first-order, not a set containment"
        )
    )
    rep.add("B hull", "B^b span all vertex B intervals", max(worst, 0.0), tol, bool(ok), note)


def _check_lmi(
    rep: VerifyReport,
    model: PolytopicModel,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    cert: dict,
    k_rtol: float,
) -> None:
    X, S, H = cert["X_list"], np.asarray(cert["S"]), np.asarray(cert["H"])
    sc = Scaling(t=np.asarray(cert["t"], float), s_u=np.asarray(cert["s_u"], float))
    if len(X) != model.n_vertices or any(
        len(X[i]) != len(model.systems[i]) for i in range(model.n_vertices)
    ):
        rep.add(
            "lmi",
            "shapes",
            float("nan"),
            float("nan"),
            False,
            "certificate X does not match the models' uncertainty vertices",
        )
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
            same = np.shape(cert[key]) == np.shape(ref) and np.allclose(
                cert[key], ref, rtol=1e-12, atol=0
            )
            rep.add(
                "lmi data",
                key,
                0.0 if same else 1.0,
                0.0,
                bool(same),
                "" if same else f"{key} differs from the one the certificate was computed with",
            )
    gam, margin = certificate_margins(model, R, C, X, S, H, sc, gamma=gamma)
    rep.add("lmi gamma", "Eq. (30) all i,j", gam, gamma, gam <= gamma)
    rep.add(
        "lmi margin",
        "Eq. (30) all i,j",
        margin,
        0.0,
        margin > 0.0,
        "min(-lambda_max(LMI), lambda_min(X))",
    )


# --------------------------------------------------------------------------- element-box certificates
#: relative tolerance of the box-containment checks (the intervals pass through YAML and npz)
BOX_TOL = 1e-9


def _sidecar_box(cert: dict, n: int, m: int) -> Optional[dict]:
    """The certified element box from the sidecar arrays as plain arrays (None when absent)."""
    need = ("box_rows", "box_cols", "box_half", "box_p", "box_Ac", "box_Bc", "box_t")
    if not all(k in cert for k in need):
        return None
    p = np.asarray(cert["box_p"], dtype=int)
    Ac, Bc = np.asarray(cert["box_Ac"], dtype=float), np.asarray(cert["box_Bc"], dtype=float)
    if Ac.ndim != 3 or Ac.shape[1:] != (n, n) or Bc.shape != (n, m) or p.shape != (Ac.shape[0],):
        return None
    out = {"Ac": Ac, "Bc": Bc, "rows": [], "cols": [], "half": [], "t": []}
    for i in range(Ac.shape[0]):
        k = int(p[i])
        for key, arr in (
            ("rows", "box_rows"),
            ("cols", "box_cols"),
            ("half", "box_half"),
            ("t", "box_t"),
        ):
            out[key].append(np.asarray(cert[arr][i, :k]))
    out["rows"] = [r.astype(int) for r in out["rows"]]
    out["cols"] = [c.astype(int) for c in out["cols"]]
    return out


def _bounds(bx: dict, i: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    AB = np.concatenate([bx["Ac"][i], bx["Bc"]], axis=1)
    lo, hi = AB.copy(), AB.copy()
    for r, c, h in zip(bx["rows"][i], bx["cols"][i], bx["half"][i]):
        lo[r, c] -= h
        hi[r, c] += h
    return lo, hi


def check_box_claim(
    rep: VerifyReport, model: PolytopicModel, raw: dict, cert_yaml: dict, bx: dict
) -> None:
    """``box claim``: every interval of the models file (read here from the raw YAML) and every
    nominal A_i, B_i lie in the certified box; the motor constants of ``uncertainty.motor_std``
    when the certificate says it added them; ``runtime set`` is checked in :func:`check_box_lmi`."""
    n, m = model.n_x, model.n_u
    boxes, k, _ = full_box_intervals(raw, None, "stored")
    worst, where = 0.0, "all vertices"
    motor_std = (cert_yaml.get("uncertainty") or {}).get("motor_std")
    for i, v in enumerate(raw.get("vertices", [])):
        lo, hi = _bounds(bx, i, n)
        scale = np.maximum(1.0, np.abs(np.concatenate([bx["Ac"][i], bx["Bc"]], axis=1)))
        AB = np.concatenate(
            [np.asarray(v["A"], dtype=float), np.asarray(v["B"], dtype=float)], axis=1
        )
        viol = np.max(np.maximum(lo - AB, AB - hi) / scale)
        if viol > worst:
            worst, where = float(viol), f"vertex {i} nominal A, B"
        eb = boxes[i]
        for isa, r, c, l_, u_ in zip(eb.is_a, eb.row, eb.col, eb.lower, eb.upper):
            cc = c if isa else n + c
            viol = max(lo[r, cc] - l_, u_ - hi[r, cc]) / scale[r, cc]
            if viol > worst:
                worst, where = float(viol), f"vertex {i} {'A' if isa else 'B'}[{r},{c}]"
        have_motor = any(
            (8 <= r < 12) and ((isa and c == r) or (not isa and c == r - 8))
            for isa, r, c in zip(eb.is_a, eb.row, eb.col)
        )
        if motor_std is not None and not have_motor and n >= 12 and m == 4:
            k_m = float((raw.get("meta") or {}).get("k_sigma", DEFAULT_K_SIGMA))
            for q in range(4):
                for cc, sd in ((8 + q, float(motor_std[0])), (n + q, float(motor_std[1]))):
                    nom = AB[8 + q, cc]
                    viol = (
                        max(lo[8 + q, cc] - (nom - k_m * sd), (nom + k_m * sd) - hi[8 + q, cc])
                        / scale[8 + q, cc]
                    )
                    if viol > worst:
                        worst, where = float(viol), f"vertex {i} motor row {8 + q}"
    ok = worst <= BOX_TOL
    rep.add(
        "box claim",
        where if not ok else f"{sum(b.row.size for b in boxes)} intervals, nominal A, B",
        worst,
        BOX_TOL,
        ok,
        "" if ok else "the certified box does not contain the identified interval",
    )


def _vertex_edges(vmin: np.ndarray, vmax: np.ndarray) -> list:
    """Per vertex and axis the (min, max) vertex indices of the edge through it (box order)."""
    import itertools

    V = np.array(list(itertools.product(*zip(vmin, vmax))), dtype=float)
    out = []
    for i in range(V.shape[0]):
        per = []
        for k in range(V.shape[1]):
            a, b = V[i].copy(), V[i].copy()
            a[k], b[k] = vmin[k], vmax[k]
            per.append(
                (
                    int(np.flatnonzero((V == a).all(axis=1))[0]),
                    int(np.flatnonzero((V == b).all(axis=1))[0]),
                    float(vmax[k] - vmin[k]),
                )
            )
        out.append(per)
    return out


def _box_block(
    form: int,
    A: np.ndarray,
    B: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    L: np.ndarray,
    Rt: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    S: np.ndarray,
    H: np.ndarray,
    Z: Optional[np.ndarray] = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Uncompressed robust block at g = 0 and the indices of its z rows (scaled data).
    form 1: dual BRL with X (= H), Y = S; forms 2, 3: Eq. (30) with X_i, S_i, H (+ Z in (1,1))."""
    n = A.shape[0]
    ne, nz, p = R.shape[1], C.shape[0], t.size
    Be = B @ R
    T = np.diag(t)
    LTL = L @ T @ L.T
    if form == 1:
        AX = A @ X + B @ S
        Rx = Rt @ np.vstack([X, S])
        Rw = Rt @ np.vstack([np.zeros((n, ne)), R])
        M = np.block(
            [
                [AX + AX.T + LTL, Be, X @ C.T, Rx.T],
                [Be.T, -np.eye(ne), np.zeros((ne, nz)), Rw.T],
                [C @ X, np.zeros((nz, ne)), np.zeros((nz, nz)), np.zeros((nz, p))],
                [Rx, Rw, np.zeros((p, nz)), -T],
            ]
        )
        z = np.arange(n + ne, n + ne + nz)
    else:
        U = A @ H + B @ S
        CH = C @ H
        Rx = Rt @ np.vstack([H, S])
        Rw = Rt @ np.vstack([np.zeros((n, ne)), R])
        Zm = np.zeros((n, n)) if Z is None else Z
        M = np.block(
            [
                [U + U.T + LTL + Zm, -X + H.T - U, Be, CH.T, Rx.T],
                [-X + H - U.T, -(H + H.T), np.zeros((n, ne)), -CH.T, -Rx.T],
                [Be.T, np.zeros((ne, n)), -np.eye(ne), np.zeros((ne, nz)), Rw.T],
                [CH, -CH, np.zeros((nz, ne)), np.zeros((nz, nz)), np.zeros((nz, p))],
                [Rx, -Rx, Rw, np.zeros((p, nz)), -T],
            ]
        )
        z = np.arange(2 * n + ne, 2 * n + ne + nz)
    return 0.5 * (M + M.T), z


def _schur_gamma(M0: np.ndarray, z: np.ndarray) -> float:
    keep = np.setdiff1d(np.arange(M0.shape[0]), z)
    P = M0[np.ix_(keep, keep)]
    if np.linalg.eigvalsh(P)[-1] >= 0:
        return float("inf")
    F = M0[np.ix_(z, keep)]
    G = F @ np.linalg.solve(-P, F.T) + M0[np.ix_(z, z)]
    return float(np.sqrt(max(np.linalg.eigvalsh(0.5 * (G + G.T))[-1], 0.0)))


def check_box_lmi(
    rep: VerifyReport,
    model: PolytopicModel,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
    cert: dict,
    k_rtol: float,
) -> None:
    """Rows ``K = S H^-1``, ``box lmi``, ``small gain``, ``runtime set`` of an element-box
    certificate (module docstring item 4b)."""
    n, m = model.n_x, model.n_u
    form = int(np.asarray(cert.get("lmi_form", 0)))
    bx = _sidecar_box(cert, n, m)
    if bx is None or form not in (1, 2, 3) or len(bx["Ac"]) != model.n_vertices:
        rep.add(
            "box lmi",
            "sidecar",
            float("nan"),
            float("nan"),
            False,
            "element-box arrays (box_*, lmi_form 1-3) missing or malformed in the sidecar",
        )
        return
    X_list, S, H = (
        cert["X_list"],
        np.asarray(cert["S"], dtype=float),
        np.asarray(cert["H"], dtype=float),
    )
    sc = Scaling(t=np.asarray(cert["t"], float), s_u=np.asarray(cert["s_u"], float))
    tau = np.r_[sc.t, sc.s_u]
    for i in range(model.n_vertices):
        K_cert = np.linalg.solve(H.T, S[i].T).T
        Ks, Kc = K[i] * sc.t[None, :] / sc.s_u[:, None], K_cert * sc.t[None, :] / sc.s_u[:, None]
        err = float(np.max(np.abs(Ks - Kc)) / max(np.max(np.abs(Kc)), 1e-300))
        rep.add("K = S H^-1", f"vertex {i}", err, k_rtol, err <= k_rtol)
    for key, ref in (("R", R), ("C", C)):
        if key in cert:
            same = np.shape(cert[key]) == np.shape(ref) and np.allclose(
                cert[key], ref, rtol=1e-12, atol=0
            )
            rep.add(
                "lmi data",
                key,
                0.0 if same else 1.0,
                0.0,
                bool(same),
                "" if same else f"{key} differs from the one the certificate was computed with",
            )
    # runtime set: every system the runtime re-checks lies in the certified box
    if "A_sys" in cert and "B_sys" in cert and "M_sys" in cert:
        worst = 0.0
        for i in range(model.n_vertices):
            lo, hi = _bounds(bx, i, n)
            scale = np.maximum(1.0, np.abs(np.concatenate([bx["Ac"][i], bx["Bc"]], axis=1)))
            for j in range(int(cert["M_sys"][i])):
                AB = np.concatenate([cert["A_sys"][i, j], cert["B_sys"][i, j]], axis=1)
                worst = max(worst, float(np.max(np.maximum(lo - AB, AB - hi) / scale)))
        rep.add(
            "runtime set",
            "sidecar A_sys, B_sys in the box",
            worst,
            BOX_TOL,
            worst <= BOX_TOL,
            ""
            if worst <= BOX_TOL
            else "a system the runtime re-checks is outside the certified set",
        )
    # the LMI, uncompressed, in the stored scaling (congruence: inertia-preserving)
    Cs = sc.C(C)
    Rs = np.asarray(R, dtype=float) / sc.s_u[:, None]
    Hs = H / (sc.t[:, None] * sc.t[None, :])
    edges = _vertex_edges(model.vmin, model.vmax) if form == 3 else None
    rate = np.asarray(cert.get("rate", []), dtype=float)
    if form == 3 and rate.shape != (model.vmin.size,):
        rep.add(
            "box lmi",
            "rate",
            float("nan"),
            float("nan"),
            False,
            "rate form without its rate bound",
        )
        return
    Xs_all = [
        np.asarray(X_list[i][0], dtype=float) / (sc.t[:, None] * sc.t[None, :])
        for i in range(model.n_vertices)
    ]
    gam, margin = 0.0, float("inf")
    for i in range(model.n_vertices):
        r, c, h, t = (
            bx["rows"][i],
            bx["cols"][i],
            bx["half"][i],
            np.asarray(bx["t"][i], dtype=float),
        )
        p = r.size
        L = np.zeros((n, p))
        L[r, np.arange(p)] = h * tau[c] / sc.t[r]
        Rt = np.zeros((p, n + m))
        Rt[np.arange(p), c] = 1.0
        ts = t / tau[c] ** 2
        A_ = sc.A(bx["Ac"][i])
        B_ = sc.Bc(bx["Bc"])
        Ss = S[i] / (sc.s_u[:, None] * sc.t[None, :])
        Zs = [None]
        if form == 3:
            Zs = []
            for signs in itertools_product_signs(model.vmin.size):
                Z = np.zeros((n, n))
                for k, (im, ip, w) in enumerate(edges[i]):
                    Z -= signs[k] * rate[k] * (Xs_all[ip] - Xs_all[im]) / w
                Zs.append(Z)
        for Z in Zs:
            M0, z = _box_block(form, A_, B_, Rs, Cs, L, Rt, ts, Xs_all[i], Ss, Hs, Z)
            gam = max(gam, _schur_gamma(M0, z))
            M = M0.copy()
            M[z, z] -= gamma**2
            margin = min(margin, float(-np.linalg.eigvalsh(M)[-1]))
        margin = min(
            margin, float(np.linalg.eigvalsh(Xs_all[i])[0]), float(np.min(ts)) if p else np.inf
        )
        # scaled small gain (KYP), independent of X and H, unscaled data
        Acl = bx["Ac"][i] + bx["Bc"] @ K[i]
        Lu = np.zeros((n, p))
        Lu[r, np.arange(p)] = h * np.sqrt(t)
        Ex = Rt @ np.vstack([np.eye(n), K[i]]) / np.sqrt(t)[:, None]
        Fw = Rt @ np.vstack([np.zeros((n, R.shape[1])), R]) / np.sqrt(t)[:, None]
        Baug = np.hstack([bx["Bc"] @ R, Lu])
        Caug = np.vstack([C / gamma, Ex])
        Daug = np.zeros((Caug.shape[0], Baug.shape[1]))
        Daug[C.shape[0] :, : R.shape[1]] = Fw
        hn = hinf_norm(Acl, Baug, Caug, D=Daug)
        rep.add(
            "small gain",
            f"vertex {i} (KYP, all delta)",
            hn.value,
            1.0,
            bool(hn.stable and hn.value < 1.0),
            "" if hn.stable else "vertex closed loop unstable",
        )
    what = {1: "common X", 2: "X_i per vertex", 3: "X(v_d), every dv_d/dt sign"}[form]
    rep.add("box lmi gamma", f"robust LMI all vertices ({what})", gam, gamma, gam <= gamma)
    rep.add(
        "box lmi margin",
        "uncompressed Schur form",
        margin,
        0.0,
        margin > 0.0,
        "min(-lambda_max(LMI), lambda_min(X), min t)",
    )


def itertools_product_signs(p: int) -> list:
    import itertools

    return [np.array(s, dtype=float) for s in itertools.product((-1.0, 1.0), repeat=p)]


def check_scheduling_claim(rep: VerifyReport, cert_yaml: dict, sidecar: Optional[dict]) -> None:
    """``scheduling``: the certificate's variation claim is the one its stored LMI proves:
    arbitrary <-> common X (form 1, or one X for every corner), rate_bounded <-> form 3 with the
    stored rate >= the claimed bound (and covers_design_signal consistent with the design
    envelope), frozen otherwise."""
    cs = cert_yaml.get("certified_set")
    if not isinstance(cs, dict) or sidecar is None:
        return
    sch = cs.get("scheduling") or {}
    var = sch.get("variation")
    form = int(np.asarray(sidecar.get("lmi_form", 0))) if "lmi_form" in sidecar else 0
    X = sidecar["X_list"]
    one_x = all(np.array_equal(X[0][0], x) for lst in X for x in lst)
    if var == "arbitrary":
        ok, why = (
            (form == 1 or (form == 0 and one_x)),
            "arbitrary variation needs one Lyapunov matrix X",
        )
    elif var == "rate_bounded":
        rate = np.asarray(sidecar.get("rate", []), dtype=float)
        claim = np.asarray(sch.get("rate_bound", []), dtype=float)
        ok = form == 3 and rate.shape == claim.shape and bool(np.all(rate >= claim * (1 - 1e-12)))
        why = "rate-bounded claim needs the rate LMI with at least the claimed bound"
        des = (cert_yaml.get("design") or {}).get("reference_rate")
        if ok and des is not None and sch.get("covers_design_signal") is not None:
            covers = bool(np.all(np.asarray(des, dtype=float) <= rate * (1 + 1e-9)))
            if bool(sch["covers_design_signal"]) != covers:
                ok, why = (
                    False,
                    "covers_design_signal contradicts the design envelope's reference_rate",
                )
    elif var == "frozen":
        ok, why = True, ""
    else:
        ok, why = False, f"unknown variation {var!r}"
    rep.add(
        "scheduling",
        f"{var} v_d (lmi_form {form})",
        0.0 if ok else 1.0,
        0.0,
        bool(ok),
        "" if ok else why,
    )


#: relative tolerance of the recomputed feedforward matrices (YAML keeps ~16 digits)
FF_RTOL = 1e-8


def check_feedforward(
    rep: VerifyReport,
    model: PolytopicModel,
    F_ff: np.ndarray,
    layout: dict,
    F_jerk: Optional[np.ndarray] = None,
    rtol: float = FF_RTOL,
) -> None:
    """Recompute F_i (and F_jerk,i) from the nominal vertex models (synthesis/feedforward.py) and
    compare with the stored ones; also the defining property: A_i dx_ff + B_i du_ff has the
    accelerated rows = a and the held rows = 0 for a = each unit vector (independent of how F was
    computed)."""
    from lpv_sysid.synthesis.feedforward import (
        FeedforwardLayout,
        feedforward_matrix,
        feedforward_residual,
        jerk_matrix,
    )

    try:
        lay = FeedforwardLayout.from_dict(layout)
        free, acc, held = lay.indices(model.state_names)
    except ConfigError as exc:
        rep.add("feedforward", "layout", 1.0, 0.0, False, str(exc))
        return
    F_ff = np.asarray(F_ff, dtype=float)
    want = (model.n_vertices, len(free) + model.n_u, len(acc))
    if F_ff.shape != want:
        rep.add(
            "feedforward", "F_ff shape", 1.0, 0.0, False, f"shape {F_ff.shape}, expected {want}"
        )
        return
    for i in range(model.n_vertices):
        try:
            F = feedforward_matrix(
                model.A[i], model.B[i], model.state_names, lay, where=f"vertex {i}"
            )
        except ConfigError as exc:
            rep.add("feedforward", f"vertex {i}", float("inf"), rtol, False, str(exc))
            continue
        err = float(np.max(np.abs(F_ff[i] - F)) / max(1.0, float(np.max(np.abs(F)))))
        rep.add(
            "feedforward",
            f"vertex {i} F_ff vs recomputed",
            err,
            rtol,
            err <= rtol,
            "" if err <= rtol else "stored F_ff differs from the one of the nominal model",
        )
        scale = max(1.0, float(np.max(np.abs(model.A[i]))), float(np.max(np.abs(model.B[i]))))
        res = max(
            float(
                np.max(
                    np.abs(
                        feedforward_residual(model.A[i], model.B[i], F_ff[i], free, acc, e)[
                            acc + held
                        ]
                    )
                )
            )
            for e in np.eye(len(acc))
        )
        ok = res <= 1e-9 * scale
        rep.add(
            "ff residual",
            f"vertex {i} A dx_ff + B du_ff - a",
            res,
            1e-9 * scale,
            ok,
            "" if ok else "stored F_ff does not produce the requested acceleration",
        )
        if lay.has_jerk:
            if F_jerk is None:
                rep.add(
                    "ff jerk",
                    f"vertex {i}",
                    1.0,
                    0.0,
                    False,
                    "layout declares the jerk term, F_jerk missing",
                )
                continue
            try:
                Fj = jerk_matrix(
                    model.A[i], model.B[i], model.state_names, F, lay, where=f"vertex {i}"
                )
            except ConfigError as exc:
                rep.add("ff jerk", f"vertex {i}", float("inf"), rtol, False, str(exc))
                continue
            Fj_s = np.asarray(F_jerk[i], dtype=float)
            if Fj_s.shape != Fj.shape:
                rep.add(
                    "ff jerk",
                    f"vertex {i} F_jerk shape",
                    1.0,
                    0.0,
                    False,
                    f"{Fj_s.shape} != {Fj.shape}",
                )
                continue
            err = float(np.max(np.abs(Fj_s - Fj)) / max(1.0, float(np.max(np.abs(Fj)))))
            rep.add(
                "ff jerk",
                f"vertex {i} F_jerk vs recomputed",
                err,
                rtol,
                err <= rtol,
                "" if err <= rtol else "stored F_jerk differs from the one of the nominal model",
            )


# --------------------------------------------------------------------------- full identified box
#: half-width multiplier of Eq. (22) when the models file records none (ident default k_sigma)
DEFAULT_K_SIGMA = 3.0


@dataclass(frozen=True)
class ElementBox:
    """Full identified intervals of one scheduling vertex (seed 0 Eq. 22): element l is
    ``A[row, col]`` (is_a) or ``B[row, col]`` in ``[lower_l, upper_l]``."""

    is_a: np.ndarray  # (p,) bool
    row: np.ndarray  # (p,) int
    col: np.ndarray  # (p,) int
    nominal: np.ndarray  # (p,)
    lower: np.ndarray  # (p,)
    upper: np.ndarray  # (p,)
    source: tuple  # (p,) "stored" | "k*std" | "fixed"

    def apply(
        self, A: np.ndarray, B: np.ndarray, theta: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
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
        k, where = (
            (float(meta["k_sigma"]), "models meta.k_sigma")
            if meta.get("k_sigma") is not None
            else (DEFAULT_K_SIGMA, "default (models file records no k_sigma)")
        )
    if not (np.isfinite(k) and k > 0):
        raise ConfigError(f"full-box check: k_sigma must be > 0, got {k!r}")
    return k, where


def full_box_intervals(
    raw: dict, k_sigma: Optional[float] = None, kept: str = "stored"
) -> tuple[list, float, str]:
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
                raise ConfigError(
                    f"models: vertices[{i}].uncertain: bad entry {e!r} ({exc})"
                ) from None
            if not all(np.isfinite([nom, std, lo, hi])) or std < 0:
                raise ConfigError(
                    f"models: vertices[{i}].uncertain {e.get('matrix')}[{r},{c}]: "
                    "non-finite bounds or negative std"
                )
            if hi > lo and kept == "stored":
                src = "stored"
            elif std > 0:
                lo, hi, src = nom - k * std, nom + k * std, "k*std"
            else:
                src = "fixed" if hi == lo else "stored"
            for key, val in zip(cols, (isa, r, c, nom, lo, hi, src)):
                cols[key].append(val)
        out.append(
            ElementBox(
                np.array(cols["is_a"], dtype=bool),
                np.array(cols["row"], dtype=int),
                np.array(cols["col"], dtype=int),
                np.array(cols["nominal"], dtype=float),
                np.array(cols["lower"], dtype=float),
                np.array(cols["upper"], dtype=float),
                tuple(cols["source"]),
            )
        )
    return out, k0, where


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
            "note": "empirical Monte Carlo over the full identified box; not claimed by the certificate",
        }


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
    """Peak frequency of sigma_max near the bisection's w0 (its bracket ends at a midpoint, O(dw) off
    the maximiser; the envelope-theorem gradient needs the maximiser). scipy bounded Brent."""
    from scipy.optimize import minimize_scalar

    from lpv_sysid.synthesis.hinf_norm import sigma_max

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
) -> FullBoxResult:
    """Monte Carlo over the full identified box (module docstring, item 5); empirical only.

    ``boxes``: :func:`full_box_intervals` (one per vertex, box order). Samples: the 2^p scheduling
    corners first (when n allows), then uniform interior v_d; per sample and per vertex the
    elements are drawn independently, uniform in their interval (even samples) or at a random
    corner of it (odd samples). ``extremes`` adds the two first-order worst corners per scheduling
    vertex (:func:`_worst_corners`). Seeded: same inputs and seed -> same samples.
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
                f"full-box check: vertex {i}: uncertain element outside A ({model.n_x}x{model.n_x}) "
                f"/ B ({model.n_x}x{model.n_u})"
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
            vd, tag = (
                model.vmin + rng.random(model.vmin.size) * (model.vmax - model.vmin),
                f"interior {k}",
            )
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
        record(
            f"{tag} {'corner-draw' if corner_draw else 'uniform'}",
            vd,
            A,
            B,
            np.tensordot(alpha, K, axes=1),
        )
    if extremes and n > 0:
        for i, vd in enumerate(verts):
            for name, th in _worst_corners(model.A[i], model.B[i], K[i], R, C, boxes[i], model.ts):
                Ai, Bi = boxes[i].apply(model.A[i], model.B[i], th)
                record(f"vertex {i} {name}", vd, Ai, Bi, K[i])
    return res


def add_full_box_rows(
    rep: VerifyReport, res: FullBoxResult, strict: bool = False, claimed: bool = False
) -> None:
    """Rows ``full-box hinf`` / ``full-box frac`` / ``full-box stab``: ``ok`` only when every sample
    passes; otherwise advisory (WARN) unless ``strict``. ``claimed``: the certificate claims this box
    (``certified_set.kind: full_identified_box``), so a miss is a broken certificate (strict)."""
    rep.full_box = res
    adv = not (strict or claimed)
    w = res.worst
    vd = "[" + ", ".join(f"{x:.3g}" for x in w.v_d) + "]" if w is not None else "-"
    tag = f"empirical, {res.n} samples, k={res.k_sigma:g}; " + (
        "cross-check of the certified full box" if claimed else "not certified"
    )
    if w is not None and not np.isnan(w.norm):
        rep.add(
            "full-box hinf",
            f"worst v_d {vd}",
            w.norm,
            res.gamma,
            res.passed,
            f"{w.where}; {tag}",
            advisory=adv,
        )
    n_ok = sum(s.ok for s in res.samples)
    rep.add(
        "full-box frac",
        f"{n_ok}/{res.n} samples ok",
        res.fraction_ok,
        1.0,
        res.passed,
        "fraction with norm <= gamma and stable",
        advisory=adv,
    )
    n_unst = sum(s.abscissa >= 0 for s in res.samples)
    rep.add(
        "full-box stab",
        "max Re eig" if res.worst is None or not np.isnan(res.worst.norm) else "max |eig| - 1",
        res.max_abscissa,
        0.0,
        res.all_stable,
        "" if res.all_stable else f"{n_unst} unstable samples",
        advisory=adv,
    )


def verify_files(
    gains_path: Path | str,
    models_path: Path | str,
    n_random: int = 20,
    seed: int = 0,
    uncertainty: Optional[dict] = None,
    velocity_index=None,
    full_box: int = 0,
    strict_full_box: bool = False,
    k_sigma: Optional[float] = None,
    full_box_kept: str = "stored",
) -> VerifyReport:
    """Load gains.yaml (+ sidecar) and vertex_models.yaml and run :func:`verify_gains`.

    Also checks names, box, equilibria and the models_sha256 of the certificate. ``full_box`` > 0
    adds the empirical Monte Carlo check over the full identified box (module docstring item 5,
    :func:`full_box_check` with ``seed``); its rows are advisory (WARN, ``passed`` unaffected)
    unless ``strict_full_box`` or the certificate claims the full box (then a miss fails: the
    Monte Carlo is a cross-check of the claim). ``k_sigma`` overrides the models file's ``meta.k_sigma``.
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
            raise ConfigError(
                f"{gains_path}: certificate.uncertainty must be a mapping, got {unc_raw!r}"
            )
        unc_cfg = dict(unc_raw)
        unc_cfg["common_b"] = isinstance(claim, dict) and claim.get("B") == "common"
    model, raw = load_models(models_path, unc_cfg)
    rep = VerifyReport()
    sha = sha256_file(models_path)
    rep.add(
        "models hash",
        Path(models_path).name,
        0.0 if sha == cert.get("models_sha256") else 1.0,
        0.0,
        sha == cert.get("models_sha256"),
        ""
        if sha == cert.get("models_sha256")
        else "models file differs from the one the gains were synthesised for",
    )
    same_names = (
        gains.state_names == model.state_names
        and gains.input_names == model.input_names
        and gains.scheduling_names == model.scheduling_names
    )
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
            rep.add(
                "sidecar", p.name, 0.0 if ok else 1.0, 0.0, ok, "" if ok else "sha256 mismatch"
            )
            if ok:
                sidecar = load_certificate_npz(p)
    if velocity_index is None and cert.get("velocity_states"):
        try:
            velocity_index = tuple(model.state_names.index(nm) for nm in cert["velocity_states"])
        except ValueError:
            rep.add(
                "velocity",
                "certificate.velocity_states",
                1.0,
                0.0,
                False,
                "names not among the states",
            )
            return rep
    if velocity_index is None:
        names = ("u", "v", "w")
        velocity_index = (
            tuple(model.state_names.index(n) for n in names)
            if all(n in model.state_names for n in names)
            else (2, 3, 4)
        )
    C = performance_matrix(gains.Q, model.n_x, velocity_index)
    if model.box is not None:
        bx = _sidecar_box(sidecar, model.n_x, model.n_u) if sidecar is not None else None
        if bx is None:
            rep.add(
                "box claim",
                "sidecar",
                1.0,
                0.0,
                False,
                "full-box certificate without its box arrays",
            )
        else:
            check_box_claim(rep, model, raw, cert, bx)
    check_scheduling_claim(rep, cert, sidecar)
    sub = verify_gains(
        model, gains.K, gains.R, C, gains.gamma, region, n_random, seed, certificate=sidecar
    )
    rep.rows.extend(sub.rows)
    ga = cert.get("gamma_achieved")
    if ga is not None:
        worst = max(
            (r.value for r in rep.rows if r.check.startswith("hinf")), default=float("nan")
        )
        rep.add(
            "gamma claim",
            "certificate.gamma_achieved",
            worst,
            float(ga) * (1 + 1e-3) + 1e-12,
            bool(worst <= float(ga) * (1 + 1e-3) + 1e-12),
            "worst independent H-inf norm vs the claimed gamma_achieved",
        )
    if full_box > 0:
        boxes, k, k_src = full_box_intervals(raw, k_sigma, full_box_kept)
        res = full_box_check(
            model,
            gains.K,
            gains.R,
            C,
            gains.gamma,
            boxes,
            n=full_box,
            seed=seed,
            k_sigma=k,
            k_source=k_src,
        )
        claimed = (
            isinstance(cert.get("certified_set"), dict)
            and cert["certified_set"].get("kind") == "full_identified_box"
            and k_sigma is None
            and full_box_kept == "stored"
        )
        add_full_box_rows(rep, res, strict=strict_full_box, claimed=claimed)
    return rep
