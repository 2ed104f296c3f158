"""vertex_models.yaml -> the uncertainty set the synthesis certifies (a PolytopicModel).

The models file is read and validated by :class:`lpv_sysid.io.formats.VertexModels` (its only
reader); this module turns that reading into the set of plants seed 0 Lemma 1 is solved for,
as configured by the ``uncertainty`` section of config/synthesis.yaml
(:class:`UncertaintySettings`): the per-vertex corner polytope of Eq. (23) (reduced when the
identified elements are too many), the common-input product polytope
(:func:`common_input_systems`, the interior of the scheduling box covered), or the full
identified element box (:func:`full_box_elements`). The gains file, its certificate and the
sidecar are written by :mod:`lpv_sysid.io.formats`.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError
from lpv_sysid.ident.vertex import DEFAULT_JOINT_PROBABILITY, UncertaintyConfig
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


#: ``uncertainty.set``: ``full_box`` = every element of the models file in its interval (the
#: structured perturbation of models.lpv.ElementBox, certified by synthesis.robust_lmi);
#: ``reduced_polytope`` = the corner polytope of Eq. (23) after the influence/box/hybrid reduction
#: (what certificates written before the full box recorded, hence the default of an absent key).
SETS = ("full_box", "reduced_polytope")
#: keys of ``uncertainty`` that configure the reduction (ident.vertex.UncertaintyConfig)
REDUCTION_KEYS = ("freq_hz", "n_freq", "output_states")
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
    reduction: Mapping[str, Any],
) -> list:
    """Eq. (23) systems of one (A, B) from stored intervals: all corners when the free elements
    fit (p <= p_max, 2**p <= max_corners), else the reduction of ident.uncertainty.build applied to
    the stored intervals (centre = midpoint, half-width = k_sigma * std with k_sigma = 1)."""
    free = [e for e in els if e.upper > e.lower]
    if len(free) <= p_max and 2 ** len(free) <= max_corners:
        return uncertainty_vertices(A, B, els, max_corners)
    from lpv_sysid.ident.vertex import uncertainty as unc

    cfg = unc.UncertaintyConfig.from_dict(
        {
            "k_sigma": 1.0,
            "method": method,
            "p_max": p_max,
            "max_corners": max_corners,
            **reduction,
        }
    )
    elements = [
        (e.matrix, e.row, e.col, 0.5 * (e.lower + e.upper), 0.5 * (e.upper - e.lower)) for e in els
    ]
    return [(np.asarray(a), np.asarray(b)) for a, b in unc.build(A, B, elements, cfg).systems]


@dataclass(frozen=True)
class UncertaintySettings:
    """The ``uncertainty`` section of config/synthesis.yaml: which set the synthesis certifies
    (seed 0 Eqs. 22-23), recorded in the certificate by :meth:`to_dict` and rebuilt from it by
    ``verify``.

    >>> UncertaintySettings.from_dict({"set": "full_box", "p_max": [4, 4]}).p_max
    (4, 4)
    >>> UncertaintySettings.from_dict({"p_max": 3}).to_dict()["p_max"]
    3
    """

    set: str = cf.choice(
        DEFAULT_SET, SETS, "full_box: every element in its interval; reduced_polytope: Eq. (23)"
    )
    motor_std: Optional[tuple] = cf.numbers(
        None,
        "[std a_Omega 1/s, std b_Omega rad/s^2] of the motor rows where the file has none",
        length=2,
        lo=0.0,
        lo_open=True,
        optional=True,
    )
    p_max: tuple = cf.counts(
        (4,), "corner parameters per vertex: one integer, or one per vertex", scalar=True
    )
    max_corners: int = cf.count(4096, "corners of one vertex polytope before reduction", lo=1)
    method: str = cf.choice(
        "influence",
        cf.specs(UncertaintyConfig)["method"].choices,
        "reduction of lpv_sysid.ident.vertex.uncertainty",
    )
    common_b: bool = cf.flag(DEFAULT_COMMON_B, "B^b common to all vertices (interior covered)")
    p_max_b: int = cf.count(DEFAULT_P_MAX_B, "corner parameters of the common input set")
    joint_probability: Optional[float] = cf.number(
        None,
        "probability that all identified elements are in the certified box at once (Sidak "
        "widening, full_box; default there: ident.vertex.DEFAULT_JOINT_PROBABILITY)",
        lo=0.0,
        lo_open=True,
        hi=1.0,
        hi_open=True,
        optional=True,
    )
    box_inflation: Optional[float] = cf.number(
        None,
        "the certified box is every half-width x (1 + box_inflation): the proof's stated "
        f"margin (full_box; default there: {DEFAULT_BOX_INFLATION})",
        lo=0.0,
        hi=1.0,
        optional=True,
    )
    interpolation: bool = cf.flag(
        True,
        "full_box: add the models file's measured interpolation error between the vertices "
        "(meta.interpolation) to every half-width",
    )
    #: keys of the reduction itself (:data:`REDUCTION_KEYS`, declared and checked by
    #: :class:`~lpv_sysid.ident.vertex.UncertaintyConfig`), passed to it as given
    reduction: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_dict(
        cls, d: Optional[Mapping[str, Any]], where: str = "uncertainty"
    ) -> "UncertaintySettings":
        d = d or {}
        kw = cf.parse_fields(cls, d, where, other_keys=REDUCTION_KEYS)
        reduction = {k: d[k] for k in REDUCTION_KEYS if k in d}
        UncertaintyConfig.from_dict(reduction, where)
        if kw.get("set", DEFAULT_SET) == "full_box":  # the full box's stated coverage and margin
            kw.setdefault("joint_probability", DEFAULT_JOINT_PROBABILITY)
            kw.setdefault("box_inflation", DEFAULT_BOX_INFLATION)
        return cls(reduction=reduction, **kw)

    def to_dict(self) -> dict:
        """The settings as recorded in ``certificate.uncertainty`` (``p_max`` an integer when
        one value serves every vertex)."""
        return {
            "set": self.set,
            "motor_std": None if self.motor_std is None else list(self.motor_std),
            "p_max": self.p_max[0] if len(self.p_max) == 1 else list(self.p_max),
            "max_corners": self.max_corners,
            "method": self.method,
            "common_b": self.common_b,
            "p_max_b": self.p_max_b,
            # a full box records both, null included (an absent key means the default)
            **{
                k: getattr(self, k)
                for k in ("joint_probability", "box_inflation", "interpolation")
                if self.set == "full_box" or k != "interpolation" and getattr(self, k) is not None
            },
            **self.reduction,
        }


def common_input_systems(
    As: np.ndarray,
    Bs: np.ndarray,
    els: Sequence[Sequence[UncertainElement]],
    p_max: int | Sequence[int],
    p_max_b: int,
    max_corners: int,
    method: str,
    reduction: Mapping[str, Any],
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
            [
                b
                for _, b in _reduced_systems(
                    A_ref, base, hull, p_max_b, max_corners, method, reduction
                )
            ]
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
        a_corners.append(
            [a for a, _ in _reduced_systems(A, B, a_els, p_a, max_a, method, reduction)]
        )
    return product_systems(a_corners, common), common


def _per_vertex(p_max: int | Sequence[int], N: int) -> list:
    """``uncertainty.p_max``: one integer for every vertex or a list of N (the seed-size
    configuration gives the vertices different corner counts, config/synthesis_seed_scale.yaml)."""
    if isinstance(p_max, int):
        p_max = (p_max,)
    vals = list(p_max) * N if len(p_max) == 1 else list(p_max)
    if len(vals) != N:
        raise ConfigError(
            f"uncertainty.p_max: a list needs one entry per vertex ({N}), got {len(vals)}"
        )
    return vals


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
    path: Path | str, uncertainty: Optional[Mapping[str, Any] | UncertaintySettings] = None
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
    ucfg = (
        uncertainty
        if isinstance(uncertainty, UncertaintySettings)
        else UncertaintySettings.from_dict(uncertainty)
    )
    p_max = _per_vertex(ucfg.p_max, len(corners))
    max_corners, p_max_b, method = ucfg.max_corners, ucfg.p_max_b, ucfg.method
    common_b, which, motor_std = ucfg.common_b, ucfg.set, ucfg.motor_std
    joint_probability, box_inflation = ucfg.joint_probability, ucfg.box_inflation
    interpolation = ucfg.interpolation
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
            As, Bs, elss, p_max, p_max_b, max_corners, method, ucfg.reduction
        )
    else:
        systems = [
            _reduced_systems(A, B, e, p, max_corners, method, ucfg.reduction)
            for A, B, e, p in zip(As, Bs, elss, p_max)
        ]
    model = PolytopicModel(systems=systems, common_input=common, **kw)
    return model, raw
