"""Independent checks of an element-box certificate (``certified_set.kind: full_identified_box``).

Rows ``box claim``, ``box lmi gamma``, ``box lmi margin``, ``small gain``, ``runtime set``,
``scheduling`` (:mod:`lpv_sysid.synthesis.verify` item 4b, docs/certificate.md section 5): the
robust LMI re-assembled in its uncompressed Schur form from the sidecar's X, S, H and
multipliers, the KYP small-gain condition independent of X and H, and the certified box against
the models file read by :func:`lpv_sysid.synthesis.verify.intervals.full_box_intervals`.
"""

from __future__ import annotations

import itertools
import logging
from typing import Optional

import numpy as np

from lpv_sysid.models.lpv import PolytopicModel
from lpv_sysid.synthesis.hinf import hinf_norm
from lpv_sysid.synthesis.scaling import Scaling
from lpv_sysid.synthesis.verify.intervals import DEFAULT_K_SIGMA, full_box_intervals
from lpv_sysid.synthesis.verify.report import (
    VerifyReport,
    check_gain_from_certificate,
    check_lmi_data,
)

log = logging.getLogger(__name__)

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
    per: dict[str, list[np.ndarray]] = {key: [] for key in ("rows", "cols", "half", "t")}
    for i in range(Ac.shape[0]):
        k = int(p[i])
        for key in per:
            per[key].append(np.asarray(cert[f"box_{key}"][i, :k]))
    per["rows"] = [r.astype(int) for r in per["rows"]]
    per["cols"] = [c.astype(int) for c in per["cols"]]
    return {"Ac": Ac, "Bc": Bc, **per}


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
    when the certificate says it added them (``runtime set``: :func:`check_box_lmi`)."""
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


def _mapping(x) -> dict:
    return x if isinstance(x, dict) else {}


def _std_meta(raw: dict) -> tuple[list, list, float]:
    """(meta.std.dof per vertex, meta.uncertainty.k_applied per vertex, meta.k_sigma or 3) of
    the raw models file."""
    meta = _mapping(raw.get("meta"))
    dofs = list(_mapping(meta.get("std")).get("dof") or [])
    ks = list(_mapping(meta.get("uncertainty")).get("k_applied") or [])
    return dofs, ks, float(meta.get("k_sigma", DEFAULT_K_SIGMA))


def _sidak_stored_k(p: int, prob: float, dof: Optional[float], k_stored: float) -> float:
    """The verifier's own Sidak half-width in stored std (the identification widened the std
    by t_nu^-1(Phi(k)) / k, docs/identification_coverage.md)."""
    from scipy import special

    a = 1.0 - prob ** (1.0 / max(p, 1))
    if dof is None:
        return float(-special.ndtri(a / 2.0))  # norm.isf
    # t.isf(a / 2, dof) / (t.ppf(norm.cdf(k_stored), dof) / k_stored)
    return float(-_t_ppf(a / 2.0, dof) / (_t_ppf(float(special.ndtr(k_stored)), dof) / k_stored))


def _t_ppf(q: float, dof: float) -> float:
    """``scipy.stats.t.ppf(q, dof)`` bit for bit (scipy 1.11: ``stdtrit(dof, q)`` inside
    (0, 1), the support's ends at 0 and 1; ``t.isf(q) = -t.ppf(q)``, ``norm.isf = -ndtri``,
    ``norm.cdf = ndtr``) without importing scipy.stats (~0.25 s of verify's serial start)."""
    from scipy import special

    if dof > 0 and q in (0.0, 1.0):  # stdtrit gives nan there
        return float("-inf") if q == 0.0 else float("inf")
    return float(special.stdtrit(dof, q))


def check_joint_claim(
    rep: VerifyReport, model: PolytopicModel, raw: dict, cert_yaml: dict, bx: dict
) -> None:
    """``joint claim``: where the certificate claims simultaneous intervals
    (``certified_set.joint_coverage.probability``), every element of the models file with a
    standard error lies in the certified box with the Sidak half-width for the number of such
    elements, recomputed here from the raw file (issue 20 item 4)."""
    jc = _mapping(_mapping(cert_yaml.get("certified_set")).get("joint_coverage"))
    prob = jc.get("probability")
    if prob is None:
        return
    n = model.n_x
    dofs, ks, k_meta = _std_meta(raw)
    verts = raw.get("vertices", [])
    p = sum(1 for v in verts for e in v.get("uncertain") or [] if float(e["std"]) > 0)
    p_claim = int(jc.get("elements", -1))
    worst, where = 0.0, f"{p} elements with a std"
    for i, v in enumerate(verts):
        lo, hi = _bounds(bx, i, n)
        scale = np.maximum(1.0, np.abs(np.concatenate([bx["Ac"][i], bx["Bc"]], axis=1)))
        dof = float(dofs[i]) if i < len(dofs) and dofs[i] is not None else None
        k = _sidak_stored_k(p_claim, float(prob), dof, float(ks[i]) if i < len(ks) else k_meta)
        for e in v.get("uncertain") or []:
            sd = float(e["std"])
            if sd <= 0:
                continue
            r, c = int(e["row"]), int(e["col"]) + (0 if e["matrix"] == "A" else n)
            nom = float(e["nominal"])
            viol = max(lo[r, c] - (nom - k * sd), (nom + k * sd) - hi[r, c]) / scale[r, c]
            if viol > worst:
                worst, where = float(viol), f"vertex {i} {e['matrix']}[{e['row']},{e['col']}]"
    ok = worst <= BOX_TOL and p_claim >= p
    rep.add(
        "joint claim",
        where,
        worst,
        BOX_TOL,
        bool(ok),
        f"Sidak over {p_claim} elements at joint probability {float(prob):g}"
        + ("" if p_claim >= p else f"; the file has {p} elements with a std, more than claimed"),
    )


def check_robust_claim(
    rep: VerifyReport, model: PolytopicModel, raw: dict, cert_yaml: dict, bx: dict
) -> None:
    """``robust claim`` (issue 20 item 6): where the certificate states
    ``certified_set.robustness.box_inflation = f``, the certified box (on which ``box lmi``
    re-proves the bound) contains every interval of the models file -- the stored one, joined
    with the simultaneous one when a joint probability is claimed -- with its half-width
    multiplied by ``1 + f`` about its centre. The bound then survives an f-fold widening."""
    cs = _mapping(cert_yaml.get("certified_set"))
    f = _mapping(cs.get("robustness")).get("box_inflation")
    if not f:
        return
    n = model.n_x
    jc = _mapping(cs.get("joint_coverage"))
    prob, p_claim = jc.get("probability"), int(jc.get("elements", 0) or 0)
    dofs, ks, k_meta = _std_meta(raw)
    # the interpolation pad of the models file when the certificate says it added it
    pad = None
    if _mapping(cs.get("interpolation")).get("source"):
        mi = _mapping(_mapping(raw.get("meta")).get("interpolation"))
        pad = np.concatenate(
            [np.asarray(mi["pad_A"], dtype=float), np.asarray(mi["pad_B"], dtype=float)], axis=1
        )
    worst, where = 0.0, f"every interval x {1 + float(f):g}"
    for i, v in enumerate(raw.get("vertices", [])):
        lo, hi = _bounds(bx, i, n)
        scale = np.maximum(1.0, np.abs(np.concatenate([bx["Ac"][i], bx["Bc"]], axis=1)))
        dof = float(dofs[i]) if i < len(dofs) and dofs[i] is not None else None
        k_i = float(ks[i]) if i < len(ks) else k_meta
        k_j = 0.0 if prob is None else _sidak_stored_k(p_claim, float(prob), dof, k_i)
        listed = set()
        for e in v.get("uncertain") or []:
            a, b = float(e["lower"]), float(e["upper"])
            nom, sd = float(e["nominal"]), float(e["std"])
            if b <= a and sd > 0:
                a, b = nom - k_i * sd, nom + k_i * sd
            if sd > 0 and k_j > 0:
                a, b = min(a, nom - k_j * sd), max(b, nom + k_j * sd)
            r, cc = int(e["row"]), int(e["col"]) + (0 if e["matrix"] == "A" else n)
            listed.add((r, cc))
            p_rc = 0.0 if pad is None else float(pad[r, cc])
            if b <= a and p_rc <= 0:
                continue
            c, h = 0.5 * (a + b), (0.5 * (b - a) + p_rc) * (1.0 + float(f))
            viol = max(lo[r, cc] - (c - h), (c + h) - hi[r, cc]) / scale[r, cc]
            if viol > worst:
                worst, where = float(viol), f"vertex {i} {e['matrix']}[{e['row']},{e['col']}]"
        if pad is not None:  # elements the file lists as fixed but the pad widens
            AB = np.concatenate([np.asarray(v["A"], float), np.asarray(v["B"], float)], axis=1)
            for r, cc in zip(*np.nonzero(pad > 0)):
                if (int(r), int(cc)) in listed:
                    continue
                h = float(pad[r, cc]) * (1.0 + float(f))
                viol = max(lo[r, cc] - (AB[r, cc] - h), (AB[r, cc] + h) - hi[r, cc])
                viol /= scale[r, cc]
                if viol > worst:
                    worst, where = float(viol), f"vertex {i} pad [{r},{cc}]"
    ok = worst <= BOX_TOL
    rep.add(
        "robust claim",
        where,
        worst,
        BOX_TOL,
        bool(ok),
        f"certified box contains every interval widened by {100 * float(f):g} %",
    )


def _vertex_edges(vmin: np.ndarray, vmax: np.ndarray) -> list:
    """Per vertex and axis the (min, max) vertex indices of the edge through it (box order)."""
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
        check_gain_from_certificate(rep, i, K[i], K_cert, sc, k_rtol)
    check_lmi_data(rep, cert, R, C)
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
        Zs: list[Optional[np.ndarray]] = [None]
        if form == 3 and edges is not None:
            Zs = []
            for signs in itertools_product_signs(model.vmin.size):
                dX = np.zeros((n, n))
                for k, (im, ip, w) in enumerate(edges[i]):
                    dX -= signs[k] * rate[k] * (Xs_all[ip] - Xs_all[im]) / w
                Zs.append(dX)
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
    """Every sign pattern of p rate directions (the rate form's vertex conditions)."""
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


def lmi_at_plant(
    cert: dict,
    vmin: np.ndarray,
    vmax: np.ndarray,
    v: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    gamma: float,
) -> float:
    """``lambda_max`` of the stored element-box LMI (sidecar ``cert``: X, S, H, t, s_u,
    lmi_form 1-3, rate; :func:`lpv_sysid.io.formats.load_certificate_npz`) evaluated at ONE
    plant ``(A, B)`` scheduled at ``v`` (issue 20: the proof at the true plant), in the stored
    scaling, with the bound ``gamma``: the certain block of :func:`check_box_lmi` (no
    perturbation rows) with ``X(alpha) = sum alpha_i X_i``, ``S(alpha) = sum alpha_i S_i`` at
    the multilinear weights ``alpha(v)`` (seed 0 Eq. 21; form 1: one X), and for form 3 the
    worst ``dX/dt`` over every sign of the recorded rate bound. ``< 0``: the stored proof holds
    at that plant (the bounded-real LMI certifies ``||u_e -> z|| < gamma`` for it frozen, with
    the same K(alpha) the runtime flies); ``nan`` for a corner certificate (form 0)."""
    from lpv_sysid.models.lpv import box_vertices, multilinear_weights

    form = int(np.asarray(cert.get("lmi_form", 0)))
    if form not in (1, 2, 3):
        return float("nan")
    n, m = B.shape
    sc = Scaling(t=np.asarray(cert["t"], float), s_u=np.asarray(cert["s_u"], float))
    tt = sc.t[:, None] * sc.t[None, :]
    Xs = [np.asarray(cert["X_list"][i][0], dtype=float) / tt for i in range(len(cert["X_list"]))]
    Ss = np.asarray(cert["S"], dtype=float) / (sc.s_u[None, :, None] * sc.t[None, None, :])
    Hs = np.asarray(cert["H"], dtype=float) / tt
    vmin, vmax = np.asarray(vmin, dtype=float), np.asarray(vmax, dtype=float)

    def X_at(vv: np.ndarray) -> np.ndarray:
        a, _ = multilinear_weights(vv, vmin, vmax)
        return np.tensordot(a, np.array(Xs), axes=1)

    v = np.asarray(v, dtype=float)
    alpha, _ = multilinear_weights(v, vmin, vmax)
    assert len(alpha) == box_vertices(vmin, vmax).shape[0] == len(Xs)
    X = np.tensordot(alpha, np.array(Xs), axes=1)
    S = np.tensordot(alpha, Ss, axes=1)
    Zs: list[Optional[np.ndarray]] = [None]
    if form == 3:
        rate = np.asarray(cert.get("rate", []), dtype=float)
        dX = []
        for k in range(vmin.size):  # X(v) is affine along each axis: exact difference
            a, b = v.copy(), v.copy()
            a[k], b[k] = vmin[k], vmax[k]
            dX.append((X_at(b) - X_at(a)) / (vmax[k] - vmin[k]))
        Zs = [
            -sum(s * rate[k] * dX[k] for k, s in enumerate(signs))
            for signs in itertools_product_signs(vmin.size)
        ]
    Rs = np.asarray(R, dtype=float) / sc.s_u[:, None]
    empty_L, empty_R = np.zeros((n, 0)), np.zeros((0, n + m))
    worst = -np.inf
    for Z in Zs:
        M, z = _box_block(
            form, sc.A(A), sc.Bc(B), Rs, sc.C(C), empty_L, empty_R, np.zeros(0), X, S, Hs, Z
        )
        M[z, z] -= gamma**2
        worst = max(worst, float(np.linalg.eigvalsh(M)[-1]))
    return worst
