"""vertex_models.yaml -> PolytopicModel, synthesis result -> gains.yaml + certificate sidecar.

File formats: ARCHITECTURE.md section 5. When :mod:`lpv_sysid.io.formats` (VertexModels,
GainSchedule with ``load``/``save`` and strict validation, DESIGN.md) is importable, its loaders
are run on every file read and written here, so both modules must agree; the conversion to the
synthesis data structures itself works on the plain YAML mapping of section 5.

Certificate sidecar: ``<gains stem>.cert.npz`` next to gains.yaml holds the LMI matrices
(X (N, M, n, n) padded with NaN for vertices with fewer uncertainty vertices, M_i, S (N, m, n),
H (n, n), the scaling t (n,), s_u (m,), R, C). The gains file's ``certificate`` entry references
it by file name and sha256, so ``verify`` can re-evaluate Eq. (30) with numpy.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
import yaml

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.lpv import (
    CommonInputSet,
    ElementBox,
    PolytopicModel,
    UncertainElement,
    box_vertices,
    input_corners,
    input_hull,
    product_systems,
    uncertainty_vertices,
)

log = logging.getLogger(__name__)

MODELS_FORMAT = "lpv_sysid/vertex_models@1"
#: models formats read here (io.formats.MODELS_FORMATS: @2 stores every element's k-sigma box)
MODELS_FORMATS = ("lpv_sysid/vertex_models@1", "lpv_sysid/vertex_models@2")
GAINS_FORMAT = "lpv_sysid/gains@1"


def sha256_file(path: Path | str) -> str:
    """SHA-256 of a file read through :func:`lpv_sysid.io.safe_open.open_regular` (regular
    files only; the npz size cap, the larger of the two caps)."""
    from lpv_sysid.io.safe_open import MAX_NPZ_BYTES, open_regular

    h = hashlib.sha256()
    with open_regular(path, max_bytes=MAX_NPZ_BYTES) as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _formats():
    try:
        from lpv_sysid.io import formats  # noqa: WPS433 - optional until io/formats.py lands
    except ImportError:
        return None
    return formats


def _layout(fm, path) -> Any:
    """The quadrotor layout (names + units strictly checked) for files with the quadrotor's
    state names, otherwise no layout (generic plants: shapes/finiteness/box still checked)."""
    try:
        d = read_yaml(
            path, "file", finite=False
        )  # a probe for the names; io.formats checks values
        names = tuple(e.get("name") if isinstance(e, dict) else e for e in d.get("states", []))
    except (ConfigError, AttributeError):
        return fm.QUADROTOR_LAYOUT
    return fm.QUADROTOR_LAYOUT if names == tuple(fm.QUADROTOR_LAYOUT.state_names) else None


def read_yaml(path: Path | str, what: str, finite: bool = True) -> dict:
    """The top-level mapping of a YAML file (:func:`lpv_sysid.io.yaml_file.read_yaml`, strict;
    ``finite``: floats must be finite and of sane magnitude)."""
    from lpv_sysid.io.yaml_file import read_yaml as _read

    p = Path(path)
    if not os.path.lexists(p):
        raise ConfigError(f"{what}: file not found: {p}")
    d = _read(p, finite=finite)
    if not isinstance(d, dict):
        raise ConfigError(f"{p}: expected a mapping at the top level")
    return d


def _matrix(v: Any, shape: tuple, where: str) -> np.ndarray:
    try:
        a = np.array(v, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: not a numeric matrix") from None
    if a.shape != shape:
        raise ConfigError(f"{where}: shape {a.shape}, expected {shape}")
    if not np.all(np.isfinite(a)):
        raise ConfigError(f"{where}: contains NaN/inf")
    return a


def _names(d: dict, key: str, where: str) -> tuple[str, ...]:
    v = d.get(key)
    if not isinstance(v, list) or not v:
        raise ConfigError(f"{where}: '{key}' must be a non-empty list")
    out = []
    for k, e in enumerate(v):
        if isinstance(e, dict) and "name" in e:
            out.append(str(e["name"]))
        elif isinstance(e, str):
            out.append(e)
        else:
            raise ConfigError(f"{where}: {key}[{k}] must be {{name, unit}}")
    return tuple(out)


def _box(d: dict, where: str) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    s = d.get("scheduling")
    if not isinstance(s, dict) or not {"names", "min", "max"} <= set(s):
        raise ConfigError(f"{where}: 'scheduling' must be {{names, min, max}}")
    names = tuple(str(n) for n in s["names"])
    lo = _matrix(s["min"], (len(names),), f"{where}: scheduling.min")
    hi = _matrix(s["max"], (len(names),), f"{where}: scheduling.max")
    return names, lo, hi


def _time(d: dict, where: str) -> Optional[float]:
    t = d.get("time", "continuous")
    if t == "continuous":
        return None
    if isinstance(t, dict) and "discrete" in t:
        ts = float(t["discrete"])
        if not ts > 0:
            raise ConfigError(f"{where}: time.discrete must be > 0")
        return ts
    raise ConfigError(f"{where}: 'time' must be 'continuous' or {{discrete: Ts}}, got {t!r}")


#: ``uncertainty.common_b`` when the key is absent: the common input-matrix polytope, so
#: Lemma 1 certifies the interior of the scheduling box, not only its vertices. ``false`` selects
#: the per-vertex B structure; older certificates are re-verified with the structure recorded in them.
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
    from lpv_sysid.ident import uncertainty as unc

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
    return u


def common_input_systems(
    As: np.ndarray,
    Bs: np.ndarray,
    els: Sequence[Sequence[UncertainElement]],
    p_max: int,
    p_max_b: int,
    max_corners: int,
    method: str,
    ucfg: dict,
) -> tuple[list, CommonInputSet]:
    """Product polytope Lambda_i^(a,b) = (A_i^a, B^b) (models.lpv module docstring).

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


def full_box_elements(
    d: dict, states: tuple, inputs: tuple, motor_std=None
) -> tuple[list, list, dict]:
    """Every uncertain element of the models file (raw mapping ``d``) in its interval, per vertex:
    ([UncertainElement], [label]) lists and a description of the rule (certificate entry).

    Interval: the stored [lower, upper] where lower < upper (format @2 stores nominal -/+ k std for
    every element); an entry stored with lower = upper and std > 0 (format @1 kept only the reduced
    polytope's corner parameters) gets nominal -/+ k std with k = ``meta.uncertainty.k_applied[i]``,
    else ``meta.k_sigma``, else 3. ``motor_std`` = (std a_Omega, std b_Omega): for a quadrotor-layout
    file whose vertex lists no motor element, A[d, d] and B[d, u] of the four motor rows get
    nominal -/+ k std (k = ``meta.k_sigma`` or 3) -- seed 0 Sec. IV treats a_Omega, b_Omega as
    uncertain (12.31 +/- 0.21, (1.399 +/- 0.182) 1e4)."""
    meta = d.get("meta") or {}
    k_meta = meta.get("k_sigma", 3.0) if isinstance(meta, dict) else 3.0
    k_applied = (
        (meta.get("uncertainty") or {}).get("k_applied") if isinstance(meta, dict) else None
    ) or []
    quad = (
        tuple(states[8:12]) == MOTOR_STATES and tuple(inputs) == MOTOR_INPUTS
        if len(states) >= 12
        else False
    )
    n_stored = n_ksig = n_motor = 0
    out, labels = [], []
    for i, v in enumerate(d["vertices"]):
        k_i = float(k_applied[i]) if i < len(k_applied) else float(k_meta)
        els, labs, seen = [], [], set()
        for e in v.get("uncertain") or []:
            el = UncertainElement.from_dict(e)
            seen.add((el.matrix, el.row, el.col))
            std = float(e.get("std", 0.0) or 0.0)
            if el.upper > el.lower:
                els.append(el)
                labs.append("stored")
                n_stored += 1
            elif std > 0:
                nom = el.nominal if el.nominal is not None else el.lower
                els.append(
                    UncertainElement(
                        el.matrix, el.row, el.col, nom - k_i * std, nom + k_i * std, nom
                    )
                )
                labs.append(f"nominal +/- {k_i:g} std")
                n_ksig += 1
        if motor_std is not None and quad:
            A = np.asarray(v["A"], dtype=float)
            B = np.asarray(v["B"], dtype=float)
            have = any(
                (m_, 8 + q, c_) in seen for q in range(4) for m_, c_ in (("A", 8 + q), ("B", q))
            )
            if not have:
                for q in range(4):
                    for mat, col, sd in (("A", 8 + q, motor_std[0]), ("B", q, motor_std[1])):
                        nom = float((A if mat == "A" else B)[8 + q, col])
                        els.append(
                            UncertainElement(
                                mat, 8 + q, col, nom - k_meta * sd, nom + k_meta * sd, nom
                            )
                        )
                        labs.append(
                            f"motor constant, synthesis config motor_std +/- {k_meta:g} std"
                        )
                        n_motor += 1
        out.append(els)
        labels.append(labs)
    rule = {
        "intervals": "stored [lower, upper] where lower < upper; nominal +/- k std where a file stores "
        "lower = upper with std > 0 (k = meta.uncertainty.k_applied, meta.k_sigma or 3)",
        "stored": n_stored,
        "k_std": n_ksig,
        "motor_from_config": n_motor,
        "motor_std": None if motor_std is None else [float(x) for x in motor_std],
    }
    return out, labels, rule


def load_models(
    path: Path | str, uncertainty: Optional[dict] = None
) -> tuple[PolytopicModel, dict]:
    """Read vertex_models.yaml into the nested polytope of seed 0 Eq. (23).

    ``uncertainty`` config (see config/synthesis.yaml): ``p_max`` (default 4) corner parameters
    per vertex, ``max_corners`` (4096), ``method`` (influence | hybrid | box) of
    :func:`lpv_sysid.ident.uncertainty.build` for the reduction, ``common_b`` and ``p_max_b``.

    ``common_b: false``: per scheduling vertex, all corners of the stored intervals [lower, upper]
    when 2**p <= ``max_corners`` and p <= ``p_max``, otherwise the reduction applied to the stored
    intervals (centre = midpoint, half-width = k_sigma * std with k_sigma = 1). B_i^j then differs
    between vertices and Lemma 1 certifies the vertices only.

    ``common_b: true``: the product polytope of :func:`common_input_systems` (B^b common to all
    vertices, so Lemma 1 covers the interior; models.lpv module docstring); ``model.common_input``
    holds the B corners. ``p_max`` may list one value per vertex.

    ``set: full_box`` (config/synthesis.yaml): every element of the file in its interval
    (:func:`full_box_elements`; ``motor_std`` adds the motor constants where the file has none),
    ``model.box`` the :class:`~lpv_sysid.models.lpv.ElementBox` the certificate covers and
    ``model.systems`` a finite sample of it (:data:`FULL_BOX_SAMPLE` per vertex: centre, nominal,
    seeded corners) for the verifier's frozen checks and the runtime's eigenvalue re-check.
    Returns (model, raw mapping).
    """
    fm = _formats()
    if fm is not None and hasattr(fm, "VertexModels"):
        fm.VertexModels.load(
            path, _layout(fm, path)
        )  # strict validation by the io/formats contract
    d = read_yaml(path, "models")
    where = str(path)
    if d.get("format") not in MODELS_FORMATS:
        raise ConfigError(
            f"{where}: 'format' must be one of {list(MODELS_FORMATS)}, got {d.get('format')!r}"
        )
    states = _names(d, "states", where)
    inputs = _names(d, "inputs", where)
    names, lo, hi = _box(d, where)
    ts = _time(d, where)
    n, m = len(states), len(inputs)
    verts = d.get("vertices")
    corners = box_vertices(lo, hi)
    if not isinstance(verts, list) or len(verts) != len(corners):
        raise ConfigError(f"{where}: 'vertices' must list {len(corners)} vertices (box corners)")
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
    As, Bs, x0s, u0s, elss = [], [], [], [], []
    for k, v in enumerate(verts):
        w = f"{where}: vertices[{k}]"
        if not isinstance(v, dict):
            raise ConfigError(f"{w}: must be a mapping")
        sch = _matrix(v.get("scheduling"), (len(names),), f"{w}.scheduling")
        if not np.allclose(sch, corners[k], rtol=1e-9, atol=1e-9):
            raise ConfigError(
                f"{w}.scheduling {sch.tolist()} is not box corner {corners[k].tolist()} "
                "(order: itertools.product over (min, max), first axis slowest)"
            )
        As.append(_matrix(v.get("A"), (n, n), f"{w}.A"))
        Bs.append(_matrix(v.get("B"), (n, m), f"{w}.B"))
        x0s.append(_matrix(v.get("x0", [0.0] * n), (n,), f"{w}.x0"))
        u0s.append(_matrix(v.get("u0", [0.0] * m), (m,), f"{w}.u0"))
        elss.append([UncertainElement.from_dict(e) for e in (v.get("uncertain") or [])])
    As, Bs = np.array(As), np.array(Bs)
    kw = dict(
        vmin=lo,
        vmax=hi,
        A=As,
        B=Bs,
        x0=np.array(x0s),
        u0=np.array(u0s),
        ts=ts,
        state_names=states,
        input_names=inputs,
        scheduling_names=names,
    )
    if which == "full_box":
        if not common_b:
            raise ConfigError(
                "uncertainty.set: full_box needs common_b: true (the B hull is what covers the "
                "interior of the scheduling box)"
            )
        fb, labels, _ = full_box_elements(d, states, inputs, motor_std)
        box = ElementBox.from_elements(As, Bs, fb, labels)
        model = PolytopicModel(
            systems=box.sample_systems(list(zip(As, Bs)), FULL_BOX_SAMPLE), box=box, **kw
        )
        return model, d
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
    return model, d


def models_dict(
    model: PolytopicModel,
    elements: Optional[Sequence[Sequence[UncertainElement]]] = None,
    state_units: Optional[Sequence[str]] = None,
    input_units: Optional[Sequence[str]] = None,
) -> dict:
    """Inverse of :func:`load_models` (for tests and examples)."""
    n, m = model.n_x, model.n_u
    sn = model.state_names or tuple(f"x{k}" for k in range(n))
    inn = model.input_names or tuple(f"u{k}" for k in range(m))
    su = state_units or ["1"] * n
    iu = input_units or ["1"] * m
    schn = model.scheduling_names or tuple(f"s{k}" for k in range(model.vmin.size))
    verts = []
    for i, vd in enumerate(model.vertices):
        e = {
            "scheduling": vd.tolist(),
            "x0": model.x0[i].tolist(),
            "u0": model.u0[i].tolist(),
            "A": model.A[i].tolist(),
            "B": model.B[i].tolist(),
            "uncertain": [],
        }
        if elements is not None:
            e["uncertain"] = [
                {
                    "matrix": el.matrix,
                    "row": el.row,
                    "col": el.col,
                    "nominal": float(
                        el.nominal if el.nominal is not None else 0.5 * (el.lower + el.upper)
                    ),
                    "std": float(0.5 * (el.upper - el.lower)),
                    "lower": float(el.lower),
                    "upper": float(el.upper),
                }
                for el in elements[i]
            ]
        verts.append(e)
    return {
        "format": MODELS_FORMAT,
        "time": "continuous" if model.ts is None else {"discrete": float(model.ts)},
        "states": [{"name": a, "unit": b} for a, b in zip(sn, su)],
        "inputs": [{"name": a, "unit": b} for a, b in zip(inn, iu)],
        "scheduling": {
            "names": list(schn),
            "min": model.vmin.tolist(),
            "max": model.vmax.tolist(),
        },
        "vertices": verts,
    }


def save_yaml(d: dict, path: Path | str) -> None:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(p.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        yaml.safe_dump(d, f, sort_keys=False, default_flow_style=None, width=1000)
    tmp.replace(p)


# --------------------------------------------------------------------------- gains
#: sidecar arrays of an element-box certificate (synthesis.robust_lmi): the certified box per vertex
#: (``box_rows``/``box_cols`` -1-padded, ``box_half`` NaN-padded, ``box_p``, centres ``box_Ac``,
#: ``box_Bc``), the S-procedure multipliers ``box_t`` (unscaled, t_l of L = h_l e_r, R = e_c^T), the
#: LMI form code ``lmi_form`` (:data:`LMI_FORMS`) and for the rate form the bound ``rate``
BOX_ARRAYS = ("box_rows", "box_cols", "box_half", "box_p", "box_Ac", "box_Bc", "box_t", "lmi_form")
#: ``lmi_form`` codes: which LMI the stored (X, S, H) satisfy
LMI_FORMS = {
    0: "eq30 corners",
    1: "box direct common X",
    2: "box eq30 vertex X_i",
    3: "box eq30 rate X(v_d)",
}


def box_arrays(
    box: ElementBox, t: Sequence[np.ndarray], form: int, rate: Optional[Sequence[float]] = None
) -> dict:
    """The :data:`BOX_ARRAYS` of an element box and its multipliers, for the sidecar."""
    N, p = box.N, max(box.p) if box.p else 0
    rows = np.full((N, p), -1, dtype=np.int64)
    cols = np.full((N, p), -1, dtype=np.int64)
    half = np.full((N, p), np.nan)
    tt = np.full((N, p), np.nan)
    for i in range(N):
        r, c, h = box.arrays(i)
        rows[i, : r.size], cols[i, : r.size], half[i, : r.size] = r, c, h
        tt[i, : r.size] = np.asarray(t[i], dtype=float)
    out = {
        "box_rows": rows,
        "box_cols": cols,
        "box_half": half,
        "box_p": np.array(box.p, dtype=np.int64),
        "box_Ac": np.asarray(box.A_centre, dtype=float),
        "box_Bc": np.asarray(box.B_centre, dtype=float),
        "box_t": tt,
        "lmi_form": np.array(int(form), dtype=np.int64),
    }
    if rate is not None:
        out["rate"] = np.asarray(rate, dtype=float)
    return out


def save_certificate_npz(
    path: Path | str,
    X: list,
    S: np.ndarray,
    H: np.ndarray,
    t: np.ndarray,
    s_u: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    systems: Optional[Sequence] = None,
    extra: Optional[dict] = None,
) -> str:
    """Write the sidecar; returns its sha256. ``systems`` (per vertex the certified (A_ij, B_ij),
    ``PolytopicModel.systems``) are stored as :data:`lpv_sysid.io.formats.SYSTEMS_ARRAYS` for the
    flight runtime's closed-loop re-check; ``extra`` adds arrays (e.g. :func:`box_arrays`)."""
    N = len(X)
    Mi = np.array([len(x) for x in X])
    n = H.shape[0]
    Xa = np.full((N, int(Mi.max()), n, n), np.nan)
    for i in range(N):
        for j in range(Mi[i]):
            Xa[i, j] = X[i][j]
    from lpv_sysid.io.safe_open import check_output

    p = Path(path)
    check_output(p)  # an existing FIFO or device is refused, not opened
    with open(p, "wb") as f:
        arrays = {} if systems is None else _formats().systems_arrays(systems)
        arrays.update(extra or {})
        np.savez(
            f,
            X=Xa,
            M=Mi,
            S=np.asarray(S),
            H=np.asarray(H),
            t=np.asarray(t),
            s_u=np.asarray(s_u),
            R=np.asarray(R),
            C=np.asarray(C),
            **arrays,
        )
    return sha256_file(p)


def load_certificate_npz(path: Path | str) -> dict:
    from lpv_sysid.io.safe_open import read_npz

    d = read_npz(path, f"{path}: certificate sidecar")
    need = {"X", "M", "S", "H", "t", "s_u"}
    if not need <= set(d):
        raise ConfigError(f"{path}: certificate sidecar misses {sorted(need - set(d))}")
    d["X_list"] = [[d["X"][i, j] for j in range(int(d["M"][i]))] for i in range(d["X"].shape[0])]
    return d


def gains_dict(
    models_raw: dict,
    model: PolytopicModel,
    K: np.ndarray,
    R: np.ndarray,
    Q: np.ndarray,
    gamma: float,
    certificate: dict,
    F_ff: Optional[np.ndarray] = None,
    ff_layout: Optional[dict] = None,
    F_jerk: Optional[np.ndarray] = None,
) -> dict:
    """The gains.yaml document of ARCHITECTURE.md section 5.

    With ``F_ff`` (N, n_free + m, p) and its layout (``FeedforwardLayout.to_dict()``) every vertex
    gets an ``F_ff`` entry and the document a top-level ``feedforward`` (synthesis/feedforward.py).
    """
    d = {
        "format": GAINS_FORMAT,
        "states": models_raw["states"],
        "inputs": models_raw["inputs"],
        "scheduling": models_raw["scheduling"],
        "vertices": [
            {
                "scheduling": model.vertices[i].tolist(),
                "K": np.asarray(K[i]).tolist(),
                "x0": model.x0[i].tolist(),
                "u0": model.u0[i].tolist(),
            }
            for i in range(model.n_vertices)
        ],
        "R": np.asarray(R).tolist(),
        "Q": np.asarray(Q).tolist(),
        "gamma": float(gamma),
        "certificate": certificate,
    }
    if F_ff is not None:
        if ff_layout is None:
            raise ConfigError("gains_dict: F_ff needs its layout (free/accelerated/held states)")
        d["feedforward"] = dict(ff_layout)
        for i, vx in enumerate(d["vertices"]):
            vx["F_ff"] = np.asarray(F_ff[i]).tolist()
            if F_jerk is not None:
                vx["F_jerk"] = np.asarray(F_jerk[i]).tolist()
    # the hash of the law just certified (the one place it is written; io.formats.certify_law)
    return _formats().certify_law(d, layout=None, label="gains")


class Gains:
    """gains.yaml in memory: K (N, m, n), x0 (N, n), u0 (N, m), R, Q, gamma, box, certificate."""

    def __init__(self, d: dict, path: Optional[Path] = None) -> None:
        where = str(path) if path else "gains"
        if d.get("format") != GAINS_FORMAT:
            raise ConfigError(
                f"{where}: 'format' must be {GAINS_FORMAT!r}, got {d.get('format')!r}"
            )
        self.raw = d
        self.path = path
        self.state_names = _names(d, "states", where)
        self.input_names = _names(d, "inputs", where)
        self.scheduling_names, self.vmin, self.vmax = _box(d, where)
        n, m = len(self.state_names), len(self.input_names)
        corners = box_vertices(self.vmin, self.vmax)
        verts = d.get("vertices")
        if not isinstance(verts, list) or len(verts) != len(corners):
            raise ConfigError(f"{where}: 'vertices' must list {len(corners)} vertices")
        K, x0, u0, F, Fj = [], [], [], [], []
        ff = d.get("feedforward")
        if ff is not None and not isinstance(ff, dict):
            raise ConfigError(f"{where}: 'feedforward' must be a mapping")
        for k, v in enumerate(verts):
            w = f"{where}: vertices[{k}]"
            if not isinstance(v, dict):
                raise ConfigError(f"{w}: must be a mapping")
            sch = _matrix(v.get("scheduling"), (corners.shape[1],), f"{w}.scheduling")
            if not np.allclose(sch, corners[k]):
                raise ConfigError(
                    f"{w}.scheduling {sch.tolist()} is not box corner {corners[k].tolist()}"
                )
            K.append(_matrix(v.get("K"), (m, n), f"{w}.K"))
            x0.append(_matrix(v.get("x0"), (n,), f"{w}.x0"))
            u0.append(_matrix(v.get("u0"), (m,), f"{w}.u0"))
            if ff is not None:
                if "F_ff" not in v:
                    raise ConfigError(f"{w}: missing F_ff (the file declares 'feedforward')")
                for key, lst in (("F_ff", F), ("F_jerk", Fj)):
                    if key in v:
                        lst.append(
                            _matrix(v[key], np.array(v[key], dtype=float).shape, f"{w}.{key}")
                        )
        self.K, self.x0, self.u0 = np.array(K), np.array(x0), np.array(u0)
        #: feedforward layout (dict) and stacked F_ff (N, r, p), or None (synthesis/feedforward.py)
        self.feedforward = ff
        self.F_ff = np.array(F) if ff is not None else None
        self.F_jerk = np.array(Fj) if ff is not None and len(Fj) == len(verts) else None
        R = np.array(d.get("R"), dtype=float)
        if R.ndim != 2 or R.shape[0] != m:
            raise ConfigError(f"{where}: R must be {m} x n_e, got shape {R.shape}")
        self.R = _matrix(d.get("R"), R.shape, f"{where}: R")
        Qa = np.array(d.get("Q"), dtype=float)
        if Qa.ndim != 2 or Qa.shape[0] != Qa.shape[1]:
            raise ConfigError(f"{where}: Q must be square, got shape {Qa.shape}")
        self.Q = _matrix(d.get("Q"), Qa.shape, f"{where}: Q")
        try:
            self.gamma = float(d["gamma"])
        except (KeyError, TypeError, ValueError):
            raise ConfigError(f"{where}: 'gamma' must be a number") from None
        if not (math.isfinite(self.gamma) and self.gamma > 0):
            raise ConfigError(f"{where}: 'gamma' must be > 0")
        cert = d.get("certificate")
        if not isinstance(cert, dict):
            raise ConfigError(f"{where}: 'certificate' must be a mapping")
        self.certificate = cert

    @classmethod
    def load(cls, path: Path | str) -> "Gains":
        fm = _formats()
        if fm is not None and hasattr(fm, "GainSchedule"):
            fm.GainSchedule.load(path, layout=_layout(fm, path))
        p = Path(path)
        return cls(read_yaml(p, "gains"), p)
