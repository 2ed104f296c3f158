"""Independent checks of the frozen closed loops and of the Eq. (30) LMIs (seed 0 Lemma 1).

Rows ``hinf``, ``hinf interior``, ``stability``, ``region``, ``common B``, ``product A``,
``structure``, ``coverage``, ``B hull``, ``K = S H^-1``, ``lmi data``, ``lmi gamma``,
``lmi margin``
(:mod:`lpv_sysid.synthesis.verify` items 1-4): H-inf norms by Hamiltonian bisection
(:mod:`lpv_sysid.synthesis.hinf.norm`) and eigenvalues with numpy, never the solver's numbers.
An element-box certificate's LMI is re-checked by :mod:`lpv_sysid.synthesis.verify.box`.
"""

from __future__ import annotations

import logging
from typing import Optional

import numpy as np

from lpv_sysid.models.lpv import PolytopicModel, common_input_deviation, multilinear_weights
from lpv_sysid.synthesis.hinf import certificate_margins, hinf_norm
from lpv_sysid.synthesis.regions import Region
from lpv_sysid.synthesis.scaling import Scaling
from lpv_sysid.synthesis.verify.box import check_box_lmi
from lpv_sysid.synthesis.verify.report import (
    VerifyReport,
    check_gain_from_certificate,
    check_lmi_data,
)

log = logging.getLogger(__name__)


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
        # discrete-time certificates are not produced by Lemma 1 (continuous): stability only
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
    """Random corner weights w_i (M_i,) per vertex (product beta_i^a beta^b for a common input
    set)."""
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
    ci = model.common_input
    if ci is None:
        return
    corners = np.asarray(ci.corners, dtype=float)
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
    exact = ci.method in ("box", "hybrid")
    if worst <= tol or exact:
        note = "" if worst <= tol else "identified B interval outside the common B corners"
        rep.add(
            "B hull", "B^b span all vertex B intervals", max(worst, 0.0), tol, worst <= tol, note
        )
        return
    # a reduced B polytope (influence/hybrid ranking) is not a containment of the identified
    # intervals and the certificate does not claim it (certified_set.kind: reduced_polytope):
    # say so (WARN, advisory) instead of printing an excess far above its limit as "ok"
    rep.add(
        "B hull",
        "identified B vs reduced corners",
        max(worst, 0.0),
        tol,
        False,
        "reduced polytope: the identified B intervals are NOT contained (not claimed; "
        "uncertainty.set: full_box certifies them)",
        advisory=True,
    )


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
        check_gain_from_certificate(rep, i, K[i], K_cert, sc, k_rtol)
    check_lmi_data(rep, cert, R, C)
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
