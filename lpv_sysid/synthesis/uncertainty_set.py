"""vertex_models.yaml -> the uncertainty set the synthesis certifies (a PolytopicModel).

The models file is read and validated by :class:`lpv_sysid.io.formats.VertexModels` (its only
reader); this module turns that reading into the set of plants seed 0 Lemma 1 is solved for,
as configured by the ``uncertainty`` section of config/synthesis.yaml
(:func:`uncertainty_settings`): the per-vertex corner polytope of Eq. (23) (reduced when the
identified elements are too many), the common-input product polytope
(:func:`common_input_systems`, the interior of the scheduling box covered), or the full
identified element box (:func:`full_box_elements`). The gains file, its certificate and the
sidecar are written by :mod:`lpv_sysid.io.formats`.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.formats import VertexModels
from lpv_sysid.models.lpv import (
    CommonInputSet,
    ElementBox,
    PolytopicModel,
    UncertainElement,
    input_corners,
    input_hull,
    product_systems,
    uncertainty_vertices,
)

log = logging.getLogger(__name__)


#: ``uncertainty.common_b`` when the key is absent: the common input-matrix polytope, so
#: Lemma 1 certifies the interior of the scheduling box, not only its vertices. ``false``
#: selects the per-vertex B structure; older certificates are re-verified with the structure
#: recorded in them.
DEFAULT_COMMON_B = True
#: ``uncertainty.p_max_b``: corner parameters of the common input set before reduction.
DEFAULT_P_MAX_B = 2


def _flag(v: Any, where: str) -> bool:
    if isinstance(v, bool):
        return v
    raise ConfigError(f"{where} must be true or false, got {v!r}")


#: ``uncertainty.set``: ``full_box`` = every element of the models file in its interval (the
#: structured perturbation of models.lpv.ElementBox, certified by synthesis.robust_lmi);
#: ``reduced_polytope`` = the corner polytope of Eq. (23) after the influence/box/hybrid reduction
#: (what certificates written before the full box recorded, hence the default of an absent key).
SETS = ("full_box", "reduced_polytope")
DEFAULT_SET = "reduced_polytope"
#: ``uncertainty.box_inflation`` of a full box: the proof covers every half-width x 1.05 (issue 20
#: item 6: a stated robustness margin instead of the solver's epsilon)
DEFAULT_BOX_INFLATION = 0.05
#: systems per vertex of the finite sample of a full box stored for the runtime re-check
FULL_BOX_SAMPLE = 16


def _reduced_systems(
    A: np.ndarray,
    B: np.ndarray,
    els: Sequence[UncertainElement],
    p_max: int,
    max_corners: int,
    method: str,
    ucfg: dict,
) -> list:
    """Eq. (23) systems of one (A, B) from stored intervals: all corners when the free elements
    fit (p <= p_max, 2**p <= max_corners), else the reduction of ident.uncertainty.build applied to
    the stored intervals (centre = midpoint, half-width = k_sigma * std with k_sigma = 1)."""
    free = [e for e in els if e.upper > e.lower]
    if len(free) <= p_max and 2 ** len(free) <= max_corners:
        return uncertainty_vertices(A, B, els, max_corners)
    from lpv_sysid.ident.vertex import uncertainty as unc

    cfg = unc.UncertaintyConfig.from_dict(
        {"k_sigma": 1.0, "method": method, "p_max": p_max, "max_corners": max_corners, **ucfg}
    )
    elements = [
        (e.matrix, e.row, e.col, 0.5 * (e.lower + e.upper), 0.5 * (e.upper - e.lower)) for e in els
    ]
    return [(np.asarray(a), np.asarray(b)) for a, b in unc.build(A, B, elements, cfg).systems]


def uncertainty_settings(uncertainty: Optional[dict]) -> dict:
    """The effective ``uncertainty`` section (defaults filled in; recorded in the certificate)."""
    u = dict(uncertainty or {})
    u.setdefault("set", DEFAULT_SET)
    if u["set"] not in SETS:
        raise ConfigError(f"uncertainty.set must be one of {SETS}, got {u['set']!r}")
    u.setdefault("p_max", 4)
    u.setdefault("max_corners", 4096)
    u.setdefault("method", "influence")
    u["common_b"] = _flag(u.get("common_b", DEFAULT_COMMON_B), "uncertainty.common_b")
    u.setdefault("p_max_b", DEFAULT_P_MAX_B)
    u.setdefault("motor_std", None)
    if u["set"] == "full_box":
        from lpv_sysid.ident.vertex import DEFAULT_JOINT_PROBABILITY

        u.setdefault("joint_probability", DEFAULT_JOINT_PROBABILITY)
        u.setdefault("box_inflation", DEFAULT_BOX_INFLATION)
    bi = u.get("box_inflation")
    if bi is not None and (
        isinstance(bi, bool) or not isinstance(bi, (int, float)) or not 0.0 <= float(bi) <= 1.0
    ):
        raise ConfigError(
            "uncertainty.box_inflation must be null or a number in [0, 1] (the certified box is "
            f"every half-width x (1 + box_inflation): the proof's stated margin), got {bi!r}"
        )
    jp = u.get("joint_probability")
    if jp is not None and (
        isinstance(jp, bool) or not isinstance(jp, (int, float)) or not 0.0 < float(jp) < 1.0
    ):
        raise ConfigError(
            "uncertainty.joint_probability must be null or a number in (0, 1) (the probability "
            f"that all identified elements are in the certified box at once), got {jp!r}"
        )
    return u


def common_input_systems(
    As: np.ndarray,
    Bs: np.ndarray,
    els: Sequence[Sequence[UncertainElement]],
    p_max: int | Sequence[int],
    p_max_b: int,
    max_corners: int,
    method: str,
    ucfg: dict,
) -> tuple[list, CommonInputSet]:
    """Product polytope Lambda_i^(a,b) = (A_i^a, B^b) (models.lpv_uncertainty module docstring).

    B part: the hull of :func:`lpv_sysid.models.lpv.input_hull`; all corners when its p_B
    elements fit (p_B <= p_max_b), else the ``method`` reduction of ident.uncertainty with
    p_max_b corner parameters (ranking frequency responses with the mean vertex A). A part: the
    per-vertex A intervals with the remaining budget p_max - ceil(log2 M_B) corner parameters and
    max_corners // M_B systems, so that M_i = M_A,i M_B stays within 2**p_max (box/influence).
    """
    base, hull, nlo, nhi = input_hull(Bs, els)
    if len(hull) <= p_max_b and 2 ** len(hull) <= max_corners:
        corners, b_method = input_corners(base, hull, max_corners), "box"
    else:
        A_ref = np.mean(As, axis=0)
        corners = np.array(
            [b for _, b in _reduced_systems(A_ref, base, hull, p_max_b, max_corners, method, ucfg)]
        )
        b_method = method
    common = CommonInputSet(corners, tuple(hull), nlo, nhi, b_method)
    M_B = common.M
    p_list = _per_vertex(p_max, len(As))
    max_a = max(1, max_corners // M_B)
    a_corners = []
    for A, B, e, p_i in zip(As, Bs, els, p_list):
        a_els = [x for x in e if x.matrix == "A"]
        p_a = max(0, p_i - int(np.ceil(np.log2(M_B))))
        a_corners.append([a for a, _ in _reduced_systems(A, B, a_els, p_a, max_a, method, ucfg)])
    return product_systems(a_corners, common), common


def _per_vertex(p_max, N: int) -> list:
    """``uncertainty.p_max``: one integer for every vertex or a list of N (the seed-size
    configuration gives the vertices different corner counts, config/synthesis_seed_scale.yaml)."""
    vals = list(p_max) if isinstance(p_max, (list, tuple)) else [p_max] * N
    if len(vals) != N:
        raise ConfigError(
            f"uncertainty.p_max: a list needs one entry per vertex ({N}), got {len(vals)}"
        )
    out = []
    for v in vals:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ConfigError(f"uncertainty.p_max entries must be integers >= 0, got {v!r}")
        out.append(int(v))
    return out


#: the quadrotor's motor rows (seed 0 Eq. 15): A[d, d] = -a_Omega, B[d, u] = b_Omega
MOTOR_STATES = ("dt", "da", "de", "dr")
MOTOR_INPUTS = ("ut", "ua", "ue", "ur")


def _meta_list(meta: dict, *keys: str) -> list:
    d: Any = meta
    for k in keys:
        d = d.get(k) if isinstance(d, dict) else None
    return list(d) if isinstance(d, (list, tuple)) else []


def _t_widening(meta: dict, i: int, k: float) -> float:
    from lpv_sysid.ident.equation_error import t_factor

    dofs = _meta_list(meta, "std", "dof")
    dof = dofs[i] if i < len(dofs) else None
    return t_factor(k, None if dof is None else float(dof))


def joint_widen(
    models: VertexModels, out: list, sigmas: list, probability: float, k_stored: list
) -> dict:
    """Widen every element with a standard error to the simultaneous interval that holds *all*
    of them at once with ``probability`` (:func:`lpv_sysid.ident.vertex.joint_k`, Sidak over the
    total count, Student-t with each vertex's ``meta.std.dof``); a stored interval already
    wider is kept. ``sigmas[i][l]``: the stored std of ``out[i][l]`` (0: no std, kept as
    stored). Returns the certificate's ``joint_coverage`` entry."""
    from lpv_sysid.ident.vertex import uncertainty as unc

    dofs = _meta_list(models.meta, "std", "dof")
    p_total = sum(1 for sv in sigmas for sd in sv if sd > 0)
    ks, widened = [], 0
    for i, (els, sv) in enumerate(zip(out, sigmas)):
        dof = dofs[i] if i < len(dofs) and dofs[i] is not None else None
        k_j = unc.joint_k(p_total, probability, None if dof is None else float(dof), k_stored[i])
        ks.append(round(k_j, 4))
        for idx, (e, sd) in enumerate(zip(els, sv)):
            if sd <= 0:
                continue
            nom = e.nominal if e.nominal is not None else 0.5 * (e.lower + e.upper)
            lo, hi = min(e.lower, nom - k_j * sd), max(e.upper, nom + k_j * sd)
            if lo < e.lower or hi > e.upper:
                widened += 1
                els[idx] = UncertainElement(e.matrix, e.row, e.col, lo, hi, nom)
    return {
        "probability": float(probability),
        "method": "Sidak over all elements with a standard error (Sidak 1967: a lower bound "
        "for jointly Gaussian estimates with any correlation), Student-t quantile with the "
        "file's meta.std.dof",
        "elements": int(p_total),
        "k_stored_std": ks,
        "widened": int(widened),
        "statement": f"all {p_total} identified elements in their intervals at once with "
        f"probability >= {probability:g} under the identification's error model "
        "(elements without a std are taken as stored)",
    }


def interpolation_widen(models: VertexModels, out: list, labels: list) -> Optional[dict]:
    """Add the models file's ``meta.interpolation`` pad (the measured multilinear interpolation
    error between the vertices, :mod:`lpv_sysid.ident.vertex.interpolation`) to every vertex's
    half-widths; an element the file lists as fixed but the pad does not gets an interval about
    its value. Returns the certificate's ``interpolation`` entry (None without a pad)."""
    meta = models.meta.get("interpolation") if isinstance(models.meta, dict) else None
    if not isinstance(meta, dict) or "pad_A" not in meta or "pad_B" not in meta:
        return None
    pad_A, pad_B = np.asarray(meta["pad_A"], dtype=float), np.asarray(meta["pad_B"], dtype=float)
    n, m = models.vertices[0].A.shape[0], models.vertices[0].B.shape[1]
    if (
        pad_A.shape != (n, n)
        or pad_B.shape != (n, m)
        or not (np.all(np.isfinite(pad_A)) and np.all(np.isfinite(pad_B)))
    ):
        raise ConfigError(
            f"meta.interpolation: pad_A {pad_A.shape} / pad_B {pad_B.shape} must be finite "
            f"{n}x{n} / {n}x{m}"
        )
    if np.any(pad_A < 0) or np.any(pad_B < 0):
        raise ConfigError("meta.interpolation: pads must be >= 0")
    added = 0
    for i, vx in enumerate(models.vertices):
        seen = {}
        for idx, e in enumerate(out[i]):
            seen[(e.matrix, e.row, e.col)] = idx
        for mat, P, M in (("A", pad_A, vx.A), ("B", pad_B, vx.B)):
            for r, c in zip(*np.nonzero(P > 0)):
                h = float(P[r, c])
                k = seen.get((mat, int(r), int(c)))
                if k is None:
                    nom = float(M[r, c])
                    out[i].append(UncertainElement(mat, int(r), int(c), nom - h, nom + h, nom))
                    labels[i].append("interpolation pad")
                    added += 1
                else:
                    e = out[i][k]
                    out[i][k] = UncertainElement(
                        e.matrix, e.row, e.col, e.lower - h, e.upper + h, e.nominal
                    )
    return {
        "source": "meta.interpolation of the models file",
        "points": meta.get("points"),
        "max_pad": float(max(pad_A.max(), pad_B.max())),
        "elements_added": added,
        "method": meta.get("method", ""),
        "statement": "every half-width + the interpolation error measured between the vertices "
        "(identified models re-expanded on a grid): the certified set holds the identified "
        "dynamics at the grid points; between them it is measured, not proven",
    }


def full_box_elements(
    models: VertexModels,
    motor_std: Optional[tuple] = None,
    joint_probability: Optional[float] = None,
    interpolation: bool = True,
) -> tuple[list, list, dict]:
    """Every uncertain element of the models file in its interval, per vertex (box order):
    ([UncertainElement], [label]) lists and a description of the rule (certificate entry).

    Interval: the stored [lower, upper] where lower < upper (format @2 stores nominal -/+ k std
    for every element); an entry stored with lower = upper and std > 0 (format @1 kept only the
    reduced polytope's corner parameters) gets nominal -/+ k std with k =
    ``meta.uncertainty.k_applied[i]``, else ``meta.k_sigma``, else 3. ``motor_std`` =
    (std a_Omega, std b_Omega): for a quadrotor-layout file whose vertex lists no motor
    element, A[d, d] and B[d, u] of the four motor rows get nominal -/+ k std (k =
    ``meta.k_sigma`` or 3) -- seed 0 Sec. IV treats a_Omega, b_Omega as uncertain
    (12.31 +/- 0.21, (1.399 +/- 0.182) 1e4)."""
    meta = models.meta
    k_meta = float(meta.get("k_sigma", 3.0))
    unc_meta = meta.get("uncertainty")
    k_applied = (unc_meta.get("k_applied") if isinstance(unc_meta, dict) else None) or []
    states, inputs = models.state_names, models.input_names
    quad = (
        tuple(states[8:12]) == MOTOR_STATES and tuple(inputs) == MOTOR_INPUTS
        if len(states) >= 12
        else False
    )
    n_stored = n_ksig = n_motor = 0
    out, labels, sigmas, k_used = [], [], [], []
    for i, vx in enumerate(models.vertices):
        k_i = float(k_applied[i]) if i < len(k_applied) else k_meta
        k_used.append(k_i)
        els, labs, seen, sv = [], [], set(), []
        for e in vx.uncertain:
            seen.add((e.matrix, e.row, e.col))
            if e.upper > e.lower or e.std > 0:
                sv.append(float(e.std))
            if e.upper > e.lower:
                els.append(e.to_lpv())
                labs.append("stored")
                n_stored += 1
            elif e.std > 0:
                nom = e.nominal
                els.append(
                    UncertainElement(
                        e.matrix, e.row, e.col, nom - k_i * e.std, nom + k_i * e.std, nom
                    )
                )
                labs.append(f"nominal +/- {k_i:g} std")
                n_ksig += 1
        if motor_std is not None and quad:
            have = any(
                (m_, 8 + q, c_) in seen for q in range(4) for m_, c_ in (("A", 8 + q), ("B", q))
            )
            if not have:
                for q in range(4):
                    for mat, col, sd in (("A", 8 + q, motor_std[0]), ("B", q, motor_std[1])):
                        nom = float((vx.A if mat == "A" else vx.B)[8 + q, col])
                        els.append(
                            UncertainElement(
                                mat, 8 + q, col, nom - k_meta * sd, nom + k_meta * sd, nom
                            )
                        )
                        labs.append(
                            f"motor constant, synthesis config motor_std +/- {k_meta:g} std"
                        )
                        # config std is not t-widened: store it as the file would
                        sv.append(float(sd) * _t_widening(models.meta, i, k_i))
                        n_motor += 1
        out.append(els)
        labels.append(labs)
        sigmas.append(sv)
    joint = (
        None
        if joint_probability is None
        else joint_widen(models, out, sigmas, float(joint_probability), k_used)
    )
    interp = interpolation_widen(models, out, labels) if interpolation else None
    rule = {
        "intervals": "stored [lower, upper] where lower < upper; nominal +/- k std where a file "
        "stores lower = upper with std > 0 (k = meta.uncertainty.k_applied, meta.k_sigma or 3)",
        "stored": n_stored,
        "k_std": n_ksig,
        "motor_from_config": n_motor,
        "motor_std": None if motor_std is None else [float(x) for x in motor_std],
    }
    if joint is not None:
        rule["joint_coverage"] = joint
    if interp is not None:
        rule["interpolation"] = interp
    return out, labels, rule


def load_models(
    path: Path | str, uncertainty: Optional[dict] = None
) -> tuple[PolytopicModel, dict]:
    """Read vertex_models.yaml into the nested polytope of seed 0 Eq. (23).

    ``uncertainty`` config (see config/synthesis.yaml): ``p_max`` (default 4) corner parameters
    per vertex, ``max_corners`` (4096), ``method`` (influence | hybrid | box) of
    :func:`lpv_sysid.ident.vertex.uncertainty.build` for the reduction, ``common_b`` and
    ``p_max_b``.

    ``common_b: false``: per scheduling vertex, all corners of the stored intervals [lower, upper]
    when 2**p <= ``max_corners`` and p <= ``p_max``, otherwise the reduction applied to the stored
    intervals (centre = midpoint, half-width = k_sigma * std with k_sigma = 1). B_i^j then differs
    between vertices and Lemma 1 certifies the vertices only.

    ``common_b: true``: the product polytope of :func:`common_input_systems` (B^b common to all
    vertices, so Lemma 1 covers the interior; models.lpv_uncertainty module docstring);
    ``model.common_input`` holds the B corners. ``p_max`` may list one value per vertex.

    ``set: full_box`` (config/synthesis.yaml): every element of the file in its interval
    (:func:`full_box_elements`; ``motor_std`` adds the motor constants where the file has none),
    ``model.box`` the :class:`~lpv_sysid.models.lpv.ElementBox` the certificate covers and
    ``model.systems`` a finite sample of it (:data:`FULL_BOX_SAMPLE` per vertex: centre, nominal,
    seeded corners) for the verifier's frozen checks and the runtime's eigenvalue re-check.
    The file is read once, by :meth:`lpv_sysid.io.formats.VertexModels.load` (strict; the
    quadrotor layout when the file names the quadrotor's states). Returns (model, the validated
    document :meth:`~lpv_sysid.io.formats.VertexModels.to_dict`: vertices in box order).
    """
    vm = VertexModels.load(path, auto_layout=True)
    raw = vm.to_dict()
    states, inputs, box = vm.state_names, vm.input_names, vm.scheduling
    corners = box.corners
    ucfg = uncertainty_settings(uncertainty)
    p_max = _per_vertex(ucfg.pop("p_max"), len(corners))
    try:
        max_corners = int(ucfg.pop("max_corners"))
        p_max_b = int(ucfg.pop("p_max_b"))
    except (TypeError, ValueError) as exc:
        raise ConfigError(
            f"uncertainty: p_max_b and max_corners must be integers ({exc})"
        ) from None
    if p_max_b < 0 or max_corners < 1:
        raise ConfigError(
            f"uncertainty: need p_max_b >= 0, max_corners >= 1, got {p_max_b}, {max_corners}"
        )
    method = str(ucfg.pop("method"))
    common_b = ucfg.pop("common_b")
    which = ucfg.pop("set")
    motor_std = ucfg.pop("motor_std", None)
    joint_probability = ucfg.pop("joint_probability", None)
    box_inflation = ucfg.pop("box_inflation", None)
    interpolation = ucfg.pop("interpolation", True)
    if not isinstance(interpolation, bool):
        raise ConfigError(
            f"uncertainty.interpolation must be true or false, got {interpolation!r}"
        )
    if motor_std is not None:
        try:
            motor_std = tuple(float(x) for x in motor_std)
        except (TypeError, ValueError):
            raise ConfigError(
                f"uncertainty.motor_std must be [std a_Omega, std b_Omega], got {motor_std!r}"
            ) from None
        if len(motor_std) != 2 or not all(np.isfinite(x) and x > 0 for x in motor_std):
            raise ConfigError(
                f"uncertainty.motor_std must be two numbers > 0, got {list(motor_std)}"
            )
    As, Bs = vm.A, vm.B
    elss = [[e.to_lpv() for e in vx.uncertain] for vx in vm.vertices]
    kw: dict[str, Any] = dict(
        vmin=box.min,
        vmax=box.max,
        A=As,
        B=Bs,
        x0=vm.x0,
        u0=vm.u0,
        ts=vm.ts,
        state_names=states,
        input_names=inputs,
        scheduling_names=box.names,
    )
    if which == "full_box":
        if not common_b:
            raise ConfigError(
                "uncertainty.set: full_box needs common_b: true (the B hull is what covers the "
                "interior of the scheduling box)"
            )
        fb, labels, rule = full_box_elements(vm, motor_std, joint_probability, interpolation)
        ebox = ElementBox.from_elements(As, Bs, fb, labels)
        cov = dict(rule.get("joint_coverage") or {})
        if "interpolation" in rule:
            cov["interpolation"] = rule["interpolation"]
        if box_inflation:
            f = 1.0 + float(box_inflation)
            ebox = dataclasses.replace(ebox, half=tuple(np.asarray(h) * f for h in ebox.half))
        if cov or box_inflation is not None:
            cov["box_inflation"] = None if box_inflation is None else float(box_inflation)
            ebox = dataclasses.replace(ebox, coverage=cov)
        model = PolytopicModel(
            systems=ebox.sample_systems(list(zip(As, Bs)), FULL_BOX_SAMPLE), box=ebox, **kw
        )
        return model, raw
    common = None
    if common_b:
        systems, common = common_input_systems(
            As, Bs, elss, p_max, p_max_b, max_corners, method, ucfg
        )
    else:
        systems = [
            _reduced_systems(A, B, e, p, max_corners, method, ucfg)
            for A, B, e, p in zip(As, Bs, elss, p_max)
        ]
    model = PolytopicModel(systems=systems, common_input=common, **kw)
    return model, raw
