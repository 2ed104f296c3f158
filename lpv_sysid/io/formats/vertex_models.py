"""``vertex_models.yaml``: the identified vertex models, strictly validated.

Format tag ``lpv_sysid/vertex_models@2``: the nominal vertex models ``(A_i, B_i)`` of seed 0
Eq. (15) at the 2^3 corners of the scheduling box (Eq. 20), their equilibria (Table 1), the
identified uncertain elements with their interval box (Eq. 22) and fit metrics (Eqs. 24-25)::

    format: lpv_sysid/vertex_models@2
    time: continuous                 # or {discrete: Ts}
    states: [{name: phi, unit: rad}, ...]          # 12, STATE_NAMES order
    inputs: [{name: ut, unit: '1'}, ...]           # 4, INPUT_NAMES order
    scheduling: {names: [u_d, v_d, w_d], min: [-5, -5, -5], max: [5, 5, 5]}
    vertices:
      - scheduling: [-5, -5, -5]
        x0: [...]; u0: [...]; A: [[...]]; B: [[...]]
        uncertain: [{matrix: A, row: 2, col: 0, nominal: -0.41, std: 0.03,
                     lower: -0.5, upper: -0.32}]
        fit: {r2: {...}, tic: {...}, nrmse: {...}}
    meta: {...}                      # optional, free-form provenance (k_sigma, method, ...)

``@2`` (:data:`MODELS_FORMAT`): ``uncertain`` lists *every* element the identification
estimated (aerodynamic elements, and the motor constants ``A[8:12, 8:12] = -a_Omega I``,
``B[8:12, :] = b_Omega I`` when identified), ``std`` is calibrated (finite-sample widened) and
``lower``/``upper`` = ``nominal -/+ k std`` with ``k`` = ``meta.k_sigma`` (3 by default;
``meta.uncertainty.k_applied`` per vertex when raised): the whole box of Eq. (22).  ``x0, u0``
is an equilibrium of the identified model.  ``@1`` (:data:`MODELS_FORMAT_V1`, still read):
``lower``/``upper`` spanned only the reduced polytope of Eq. (23) that the identification
chose (most entries ``lower = upper = nominal``), the full box following from ``std`` and
``meta.k_sigma``; :attr:`VertexModels.format_version` tells them apart and ``save`` keeps it.

Channel lists, time base, box and vertex order: :mod:`lpv_sysid.io.formats.shared`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Optional, Sequence

import numpy as np

from lpv_sysid.io.files import read_located, save_yaml, sha256_file
from lpv_sysid.io.formats.field_checker import FieldChecker, floats, kind_of, rows
from lpv_sysid.io.formats.shared import (
    QUADROTOR_LAYOUT,
    Layout,
    SchedulingBox,
    StackedVertices,
    layout_of,
    order_vertices,
    parse_channels,
    parse_time,
    time_dict,
)

if TYPE_CHECKING:
    from lpv_sysid.models.lpv import PolytopicModel, UncertainElement


MODELS_FORMAT = "lpv_sysid/vertex_models@2"
MODELS_FORMAT_V1 = "lpv_sysid/vertex_models@1"
MODELS_FORMATS = {MODELS_FORMAT_V1: 1, MODELS_FORMAT: 2}


@dataclass(frozen=True)
class UncertainEntry:
    """One identified element with its interval (seed 0 Eq. 22)."""

    matrix: str
    row: int
    col: int
    nominal: float
    std: float
    lower: float
    upper: float

    def to_dict(self) -> dict:
        return {
            "matrix": self.matrix,
            "row": int(self.row),
            "col": int(self.col),
            "nominal": float(self.nominal),
            "std": float(self.std),
            "lower": float(self.lower),
            "upper": float(self.upper),
        }

    @classmethod
    def parse(cls, v: FieldChecker, d, path: str, n_x: int, n_u: int) -> "UncertainEntry":
        v.mapping(d, path, ("matrix", "row", "col", "nominal", "std", "lower", "upper"))
        mat = d["matrix"]
        if mat not in ("A", "B"):
            v.fail(f"{path}.matrix", f"expected 'A' or 'B', got {mat!r}")
        rows, cols = (n_x, n_x) if mat == "A" else (n_x, n_u)
        row = v.integer(d["row"], f"{path}.row")
        col = v.integer(d["col"], f"{path}.col")
        if not 0 <= row < rows:
            v.fail(f"{path}.row", f"{row} outside 0..{rows - 1} of {mat} ({rows}x{cols})")
        if not 0 <= col < cols:
            v.fail(f"{path}.col", f"{col} outside 0..{cols - 1} of {mat} ({rows}x{cols})")
        nom, std = v.number(d["nominal"], f"{path}.nominal"), v.number(d["std"], f"{path}.std")
        lo, hi = v.number(d["lower"], f"{path}.lower"), v.number(d["upper"], f"{path}.upper")
        if std < 0:
            v.fail(f"{path}.std", f"must be >= 0, got {std}")
        if not lo <= nom <= hi:
            v.fail(path, f"need lower <= nominal <= upper, got {lo} <= {nom} <= {hi}")
        return cls(mat, row, col, nom, std, lo, hi)

    def to_lpv(self):
        """The :class:`lpv_sysid.models.lpv.UncertainElement` of this entry."""
        from lpv_sysid.models.lpv import UncertainElement

        return UncertainElement(
            matrix=self.matrix,
            row=self.row,
            col=self.col,
            lower=self.lower,
            upper=self.upper,
            nominal=self.nominal,
        )


def _fit(v: FieldChecker, d, path: str) -> dict:
    v.mapping(d, path, (), extra_ok=True)
    out: dict = {}
    for metric, per in d.items():
        v.mapping(per, f"{path}.{metric}", (), extra_ok=True)
        out[metric] = {}
        for ch, x in per.items():
            out[metric][str(ch)] = v.number(
                x, f"{path}.{metric}.{ch}", bounded=False
            )  # r2 of a flat axis: -1e20
    return out


@dataclass(frozen=True)
class VertexModel:
    """Nominal model at one scheduling corner: ``dx_dot = A dx + B du`` about ``(x0, u0)``."""

    scheduling: np.ndarray
    x0: np.ndarray
    u0: np.ndarray
    A: np.ndarray
    B: np.ndarray
    uncertain: tuple = ()
    fit: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d: dict[str, Any] = {
            "scheduling": floats(self.scheduling),
            "x0": floats(self.x0),
            "u0": floats(self.u0),
            "A": rows(self.A),
            "B": rows(self.B),
            "uncertain": [e.to_dict() for e in self.uncertain],
        }
        if self.fit:
            d["fit"] = {m: {k: float(x) for k, x in per.items()} for m, per in self.fit.items()}
        return d

    @classmethod
    def parse(cls, v: FieldChecker, d, i: int, n_x: int, n_u: int, n_p: int) -> "VertexModel":
        p = f"vertices[{i}]"
        v.mapping(d, p, ("scheduling", "x0", "u0", "A", "B"), ("uncertain", "fit"))
        unc = d.get("uncertain") or []
        if not isinstance(unc, list):
            v.fail(f"{p}.uncertain", f"expected a list, got {kind_of(unc)}")
        entries = tuple(
            UncertainEntry.parse(v, e, f"{p}.uncertain[{k}]", n_x, n_u) for k, e in enumerate(unc)
        )
        seen: dict[tuple, int] = {}
        for k, e in enumerate(entries):
            key = (e.matrix, e.row, e.col)
            if key in seen:
                v.fail(
                    f"{p}.uncertain[{k}]",
                    f"{e.matrix}[{e.row}][{e.col}] already given by uncertain[{seen[key]}]",
                )
            seen[key] = k
        return cls(
            scheduling=v.vector(d["scheduling"], n_p, f"{p}.scheduling"),
            x0=v.vector(d["x0"], n_x, f"{p}.x0"),
            u0=v.vector(d["u0"], n_u, f"{p}.u0"),
            A=v.matrix(d["A"], (n_x, n_x), f"{p}.A"),
            B=v.matrix(d["B"], (n_x, n_u), f"{p}.B"),
            uncertain=entries,
            fit=_fit(v, d["fit"], f"{p}.fit") if d.get("fit") is not None else {},
        )


@dataclass(frozen=True)
class VertexModels(StackedVertices):
    """Contents of ``vertex_models.yaml``; ``vertices`` in box order."""

    state_names: tuple
    state_units: tuple
    input_names: tuple
    input_units: tuple
    scheduling: SchedulingBox
    vertices: tuple
    ts: Optional[float] = None  # None: continuous time
    meta: dict = field(default_factory=dict)
    format_version: int = 2  # 1: lower/upper span the reduced polytope (module docstring)

    @property
    def A(self) -> np.ndarray:
        return self._stacked("A")

    @property
    def B(self) -> np.ndarray:
        return self._stacked("B")

    def to_polytopic(self, max_corners: Optional[int] = None):
        """:class:`lpv_sysid.models.lpv.PolytopicModel` with the Eq. (23) uncertainty vertices."""
        from lpv_sysid.models import lpv

        kw = {} if max_corners is None else {"max_corners": max_corners}
        return lpv.PolytopicModel.from_uncertain_elements(
            self.scheduling.min,
            self.scheduling.max,
            self.A,
            self.B,
            self.x0,
            self.u0,
            [[e.to_lpv() for e in vx.uncertain] for vx in self.vertices],
            ts=self.ts,
            state_names=self.state_names,
            input_names=self.input_names,
            scheduling_names=self.scheduling.names,
            **kw,
        )

    def to_dict(self) -> dict:
        tag = {v: k for k, v in MODELS_FORMATS.items()}[self.format_version]
        d = {
            "format": tag,
            "time": time_dict(self.ts),
            "states": [{"name": n, "unit": u} for n, u in zip(self.state_names, self.state_units)],
            "inputs": [{"name": n, "unit": u} for n, u in zip(self.input_names, self.input_units)],
            "scheduling": self.scheduling.to_dict(),
            "vertices": [vx.to_dict() for vx in self.vertices],
        }
        if self.meta:
            d["meta"] = self.meta
        return d

    @classmethod
    def from_dict(
        cls, d, layout: Optional[Layout] = QUADROTOR_LAYOUT, label: str = "vertex_models.yaml"
    ) -> "VertexModels":
        """Validate and build; ``layout=None`` accepts any names/units (shapes from the lists)."""
        v = FieldChecker(label)
        lay = layout or Layout()
        v.mapping(
            d, "", ("format", "time", "states", "inputs", "scheduling", "vertices"), ("meta",)
        )
        if not isinstance(d["format"], str) or d["format"] not in MODELS_FORMATS:
            v.fail(
                "format",
                f"expected {MODELS_FORMAT!r} (or {MODELS_FORMAT_V1!r}), got {d['format']!r}",
            )
        ts = parse_time(v, d["time"])
        sn, su = parse_channels(v, d["states"], "states", lay.state_names, lay.state_units)
        inn, inu = parse_channels(v, d["inputs"], "inputs", lay.input_names, lay.input_units)
        box = SchedulingBox.parse(v, d["scheduling"], lay.scheduling_names)
        if not isinstance(d["vertices"], list):
            v.fail("vertices", f"expected a list, got {kind_of(d['vertices'])}")
        vxs = [
            VertexModel.parse(v, e, i, len(sn), len(inn), len(box.names))
            for i, e in enumerate(d["vertices"])
        ]
        order = order_vertices(v, [vx.scheduling for vx in vxs], box)
        meta = d.get("meta") or {}
        if not isinstance(meta, Mapping):
            v.fail("meta", f"expected a mapping, got {kind_of(meta)}")
        return cls(
            sn,
            su,
            inn,
            inu,
            box,
            tuple(vxs[k] for k in order),
            ts,
            dict(meta),
            MODELS_FORMATS[d["format"]],
        )

    @classmethod
    def load(
        cls, path, layout: Optional[Layout] = QUADROTOR_LAYOUT, *, auto_layout: bool = False
    ) -> "VertexModels":
        """Read (once) and validate; ``auto_layout``: the layout :func:`layout_of` picks from
        the document (the quadrotor's when it names the quadrotor's states, else none)."""
        path = Path(path)
        doc = read_located(path)
        return cls.from_dict(doc, layout_of(doc) if auto_layout else layout, label=path.name)

    def save(self, path) -> str:
        """Write the file (validated first, written atomically); returns its SHA-256."""
        doc = self.to_dict()
        self.from_dict(doc, layout=None, label=Path(path).name)  # never write an invalid file
        save_yaml(doc, path)
        return sha256_file(path)


def models_dict(
    model: "PolytopicModel",
    elements: Optional[Sequence[Sequence["UncertainElement"]]] = None,
    state_units: Optional[Sequence[str]] = None,
    input_units: Optional[Sequence[str]] = None,
) -> dict:
    """The ``vertex_models.yaml`` document of a :class:`~lpv_sysid.models.lpv.PolytopicModel`
    (its vertex models and equilibria) with ``elements`` per vertex as the ``uncertain``
    entries (``std`` = half the interval width); default names ``x0..``, ``u0..``, ``s0..``
    and units ``'1'``. For tests, examples and the rate-plant identification."""
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
        "format": MODELS_FORMAT_V1,  # lower/upper as given (the polytope), std = half-width
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
