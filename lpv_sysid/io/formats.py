"""``vertex_models.yaml`` and ``gains.yaml`` (ARCHITECTURE.md section 5), strictly validated.

``vertex_models.yaml`` (format tag ``lpv_sysid/vertex_models@2``): the nominal vertex
models ``(A_i, B_i)`` of seed 0 Eq. (15) at the 2^3 corners of the scheduling box
(Eq. 20), their equilibria (Table 1), the identified uncertain elements with their
interval box (Eq. 22) and fit metrics (Eqs. 24-25)::

    format: lpv_sysid/vertex_models@2
    time: continuous                 # or {discrete: Ts}
    states: [{name: phi, unit: rad}, ...]          # 12, STATE_NAMES order
    inputs: [{name: ut, unit: '1'}, ...]           # 4, INPUT_NAMES order
    scheduling: {names: [u_d, v_d, w_d], min: [-5, -5, -5], max: [5, 5, 5]}
    vertices:
      - scheduling: [-5, -5, -5]
        x0: [...]; u0: [...]; A: [[...]]; B: [[...]]
        uncertain: [{matrix: A, row: 2, col: 0, nominal: -0.41, std: 0.03, lower: -0.5, upper: -0.32}]
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

``gains.yaml`` (``lpv_sysid/gains@1``): vertex gains ``K_i`` (Eq. 31, ``du_c = K dx``),
excitation input matrix ``R`` (Eq. 27), performance scaling ``Q`` (Eq. 28), the bound
``gamma`` and the certificate of seed 0 Lemma 1 with ``models_sha256`` = SHA-256 of the
bytes of the models file the gains were synthesised for, ``gains_sha256`` = the hash of
the certified law (:meth:`GainSchedule.law_sha256`), ``design`` = the phase-2 signal
envelope the gains were designed for (:class:`DesignEnvelope`) and ``sidecar`` = the
certificate sidecar holding the certified systems (:data:`SYSTEMS_ARRAYS`), all three
required by the flight runtime; ``certified_set`` (written by ``lpv-sysid synthesize``,
docs/certificate.md) says exactly which plants and which scheduling signals the bound covers:
``kind`` (``full_identified_box``: every element of the models file in its interval, the box
itself in the sidecar; ``reduced_polytope``: the convex hull of the sidecar's Eq. (23) systems)
and ``scheduling.variation`` (``frozen`` v_d, ``arbitrary`` rate: one Lyapunov matrix, or
``rate_bounded`` with ``rate_bound``); the systems the runtime re-checks (sidecar ``A_sys``,
``B_sys``) are members of that set. Optional reference feedforward
(:mod:`lpv_sysid.synthesis.feedforward`): a top-level ``feedforward: {free_states,
accelerated_states, held_states}`` and, then required at every vertex, ``F_ff`` with
``len(free_states) + n_u`` rows (free states in the listed order, then the inputs) and one
column per accelerated state; with ``kinematic_states`` and ``rate_states`` in ``feedforward`` also
``F_jerk`` (rows: free states, inputs, rate states; the jerk term). A file without
``feedforward`` has no feedforward (older files).

Validation is strict: format tag, unknown/missing keys, names and units (by default the
quadrotor layout of :mod:`lpv_sysid.models.quadrotor`), matrix shapes, finiteness, the box
(``min < max``; the vertices are exactly the 2^p corners, each once) and the uncertain
entries. Every error is a :class:`ConfigError` whose message starts with the file name and
the field path, e.g. ``gains.yaml: vertices[3].K: expected shape 4x12, got 4x11``.

Vertices are stored in the box order of :func:`lpv_sysid.models.lpv.box_vertices`
(``itertools.product`` over ``(min_k, max_k)``, first axis slowest); a file listing the
corners in another order is accepted and re-ordered, and is written back in box order.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np
import yaml

from lpv_sysid.errors import ConfigError

__all__ = [
    "MODELS_FORMAT",
    "MODELS_FORMAT_V1",
    "MODELS_FORMATS",
    "GAINS_FORMAT",
    "Layout",
    "QUADROTOR_LAYOUT",
    "SchedulingBox",
    "UncertainEntry",
    "VertexModel",
    "VertexModels",
    "GainVertex",
    "FeedforwardSpec",
    "Certificate",
    "GainSchedule",
    "load_yaml",
    "sha256_file",
    "sha256_bytes",
    "DesignEnvelope",
    "certify_law",
    "SYSTEMS_ARRAYS",
    "systems_arrays",
    "load_certified_systems",
]

MODELS_FORMAT = "lpv_sysid/vertex_models@2"
MODELS_FORMAT_V1 = "lpv_sysid/vertex_models@1"
MODELS_FORMATS = {MODELS_FORMAT_V1: 1, MODELS_FORMAT: 2}
GAINS_FORMAT = "lpv_sysid/gains@1"


# ---------------------------------------------------------------------------- layout
@dataclass(frozen=True)
class Layout:
    """Expected channel names and units; ``None`` fields are not checked."""

    state_names: Optional[tuple] = None
    state_units: Optional[tuple] = None
    input_names: Optional[tuple] = None
    input_units: Optional[tuple] = None
    scheduling_names: Optional[tuple] = None


def _quadrotor_layout() -> Layout:
    # The single place the expected names live: models/quadrotor.py (DESIGN.md state order).
    from lpv_sysid.models import quadrotor as qr

    return Layout(
        tuple(qr.STATE_NAMES),
        tuple(qr.STATE_UNITS),
        tuple(qr.INPUT_NAMES),
        tuple(qr.INPUT_UNITS),
        tuple(qr.SCHEDULING_NAMES),
    )


QUADROTOR_LAYOUT = _quadrotor_layout()


# ------------------------------------------------------------------------ yaml I/O
def load_yaml(path, label: Optional[str] = None) -> Any:
    """Parse a YAML file; a syntax error becomes ``ConfigError`` with line and column.

    The file is read by :func:`lpv_sysid.io.safe_open.read_text` (regular file, size cap,
    UTF-8) and parsed by the strict loader of :mod:`lpv_sysid.io.yaml_file` (duplicate keys,
    nesting depth, alias expansion, integer range).
    """
    from lpv_sysid.io.safe_open import read_text

    path = Path(path)
    label = label or path.name
    text = read_text(path, label, show_path=True)
    return parse_yaml(text, label)


def parse_yaml(text: str, label: str) -> Any:
    from lpv_sysid.io.yaml_file import strict_load

    try:
        return strict_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = (
            getattr(exc, "problem", None) or (str(exc).splitlines() or [type(exc).__name__])[0]
        )
        raise ConfigError(f"{label}: malformed YAML{where}: {problem}") from None


class _Dumper(yaml.SafeDumper):
    """Block style for mappings, flow style for vectors and matrix rows."""


def _represent_list(dumper, data):
    flow = all(not isinstance(v, (list, dict)) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def _write_yaml(path, doc: dict, label: str) -> None:
    """Atomic write (temporary file + rename) so a failure never leaves half a file."""
    path = Path(path)
    text = yaml.dump(
        doc,
        Dumper=_Dumper,
        sort_keys=False,
        default_flow_style=False,
        width=100,
        allow_unicode=True,
    )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
    except OSError as exc:
        raise ConfigError(f"{label}: cannot write {path}: {exc.strerror or exc}") from None


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path) -> str:
    """SHA-256 (hex) of the file's bytes -- ``certificate.models_sha256``."""
    from lpv_sysid.io.safe_open import read_bytes

    return sha256_bytes(read_bytes(path, Path(path).name, show_path=True))


# ---------------------------------------------------------------------- validators
class _V:
    """Field-path aware validators: every error is ``ConfigError("<label>: <path>: ...")``."""

    def __init__(self, label: str):
        self.label = label

    def fail(self, path: str, msg: str):
        raise ConfigError(f"{self.label}: {path}: {msg}" if path else f"{self.label}: {msg}")

    def mapping(
        self,
        d,
        path: str,
        required: Sequence[str],
        optional: Sequence[str] = (),
        extra_ok: bool = False,
    ) -> Mapping:
        if not isinstance(d, Mapping):
            self.fail(path, f"expected a mapping, got {_kind(d)}")
        bad = [k for k in d if not isinstance(k, str)]
        if bad:
            self.fail(path, f"keys must be strings, got {bad}")
        missing = [k for k in required if k not in d]
        if missing:
            self.fail(path, f"missing key(s) {missing}")
        if not extra_ok:
            unknown = [k for k in d if k not in required and k not in optional]
            if unknown:
                self.fail(
                    path, f"unknown key(s) {unknown}; allowed: {list(required) + list(optional)}"
                )
        return d

    def number(self, v, path: str, bounded: bool = True) -> float:
        """A finite number; with ``bounded`` (all fields but fit metrics) also
        ``|x| <= MAX_MAGNITUDE`` (io.yaml_file: larger entries overflow downstream products)."""
        from lpv_sysid.io.yaml_file import MAX_MAGNITUDE

        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(path, f"expected a number, got {_kind(v)} {v!r}")
        try:
            x = float(v)
        except OverflowError:
            self.fail(
                path, f"out of range for a double, got an integer of {len(str(abs(v)))} digits"
            )
        if not math.isfinite(x):
            self.fail(path, f"must be finite, got {x}")
        if bounded and abs(x) > MAX_MAGNITUDE:
            self.fail(path, f"magnitude must be <= {MAX_MAGNITUDE:g}, got {x:g}")
        return x

    def integer(self, v, path: str) -> int:
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(path, f"expected an integer, got {_kind(v)} {v!r}")
        return int(v)

    def string(self, v, path: str, nonempty: bool = True) -> str:
        if not isinstance(v, str) or (nonempty and not v):
            self.fail(
                path, f"expected a{' non-empty' if nonempty else ''} string, got {_kind(v)} {v!r}"
            )
        return v

    def vector(self, v, n: Optional[int], path: str) -> np.ndarray:
        if not isinstance(v, (list, tuple, np.ndarray)):
            self.fail(
                path, f"expected a list of {n if n is not None else ''} numbers, got {_kind(v)}"
            )
        vals = [self.number(x, f"{path}[{i}]") for i, x in enumerate(v)]
        if n is not None and len(vals) != n:
            self.fail(path, f"expected {n} values, got {len(vals)}")
        return np.array(vals, dtype=float)

    def matrix(self, v, shape: tuple, path: str) -> np.ndarray:
        rows, cols = shape
        if not isinstance(v, (list, tuple, np.ndarray)) or any(
            not isinstance(r, (list, tuple, np.ndarray)) for r in v
        ):
            self.fail(path, f"expected a {rows}x{cols} matrix as a list of rows, got {_kind(v)}")
        lens = sorted({len(r) for r in v})
        if len(v) != rows or lens != [cols]:
            got = f"{len(v)}x{lens[0]}" if len(lens) == 1 else f"{len(v)} rows of lengths {lens}"
            self.fail(path, f"expected shape {rows}x{cols}, got {got}")
        return np.array(
            [
                [self.number(x, f"{path}[{i}][{j}]") for j, x in enumerate(r)]
                for i, r in enumerate(v)
            ],
            dtype=float,
        ).reshape(rows, cols)


def _kind(v) -> str:
    return {dict: "mapping", list: "list", str: "string", type(None): "null", bool: "boolean"}.get(
        type(v), type(v).__name__
    )


def _floats(a) -> list:
    return [float(x) for x in np.asarray(a, dtype=float).ravel()]


def _rows(a) -> list:
    return [[float(x) for x in row] for row in np.asarray(a, dtype=float)]


# ------------------------------------------------------------------ shared pieces
def _channels(v: _V, d, path: str, names: Optional[tuple], units: Optional[tuple]):
    if not isinstance(d, list) or not d:
        v.fail(path, f"expected a non-empty list of {{name, unit}}, got {_kind(d)}")
    got_n, got_u = [], []
    for i, e in enumerate(d):
        v.mapping(e, f"{path}[{i}]", ("name", "unit"))
        got_n.append(v.string(e["name"], f"{path}[{i}].name"))
        got_u.append(v.string(e["unit"], f"{path}[{i}].unit"))
    if len(set(got_n)) != len(got_n):
        v.fail(path, f"duplicate names in {got_n}")
    if names is not None:
        if len(got_n) != len(names):
            v.fail(path, f"expected {len(names)} entries {list(names)}, got {len(got_n)}")
        for i, (g, e) in enumerate(zip(got_n, names)):
            if g != e:
                v.fail(f"{path}[{i}].name", f"expected {e!r}, got {g!r}")
    if units is not None and names is not None:
        for i, (g, e) in enumerate(zip(got_u, units)):
            if g != e:
                v.fail(f"{path}[{i}].unit", f"expected {e!r} for {got_n[i]!r}, got {g!r}")
    return tuple(got_n), tuple(got_u)


def _time(v: _V, d, path: str = "time") -> Optional[float]:
    """``continuous`` -> None; ``{discrete: Ts}`` -> Ts (> 0)."""
    if d == "continuous":
        return None
    if isinstance(d, Mapping):
        v.mapping(d, path, ("discrete",))
        ts = v.number(d["discrete"], f"{path}.discrete")
        if ts <= 0:
            v.fail(f"{path}.discrete", f"sample time must be > 0, got {ts}")
        return ts
    v.fail(path, f"expected 'continuous' or {{discrete: Ts}}, got {d!r}")


def _time_dict(ts: Optional[float]):
    return "continuous" if ts is None else {"discrete": float(ts)}


@dataclass(frozen=True)
class SchedulingBox:
    """Scheduling box of seed 0 Eq. (20): ``names``, ``min`` < ``max`` per axis."""

    names: tuple
    min: np.ndarray
    max: np.ndarray

    @property
    def corners(self) -> np.ndarray:
        """The 2^p corners, first axis slowest (= :func:`lpv_sysid.models.lpv.box_vertices`)."""
        return np.array(list(itertools.product(*zip(self.min, self.max))), dtype=float)

    def to_dict(self) -> dict:
        return {"names": list(self.names), "min": _floats(self.min), "max": _floats(self.max)}

    @classmethod
    def parse(cls, v: _V, d, names: Optional[tuple], path: str = "scheduling") -> "SchedulingBox":
        v.mapping(d, path, ("names", "min", "max"))
        if not isinstance(d["names"], list) or not d["names"]:
            v.fail(f"{path}.names", f"expected a non-empty list of names, got {_kind(d['names'])}")
        got = tuple(v.string(n, f"{path}.names[{i}]") for i, n in enumerate(d["names"]))
        if names is not None and got != tuple(names):
            v.fail(f"{path}.names", f"expected {list(names)}, got {list(got)}")
        if len(set(got)) != len(got):
            v.fail(f"{path}.names", f"duplicate names in {list(got)}")
        lo = v.vector(d["min"], len(got), f"{path}.min")
        hi = v.vector(d["max"], len(got), f"{path}.max")
        for k in range(len(got)):
            if not lo[k] < hi[k]:
                v.fail(path, f"need min < max on axis {got[k]!r}, got min={lo[k]:g} max={hi[k]:g}")
        return cls(got, lo, hi)

    def same_as(self, other: "SchedulingBox") -> bool:
        return (
            self.names == other.names
            and np.array_equal(self.min, other.min)
            and np.array_equal(self.max, other.max)
        )


def _order_vertices(v: _V, points: list, box: SchedulingBox) -> list[int]:
    """Index permutation putting the vertices into box order; each corner exactly once."""
    corners = box.corners
    scale = np.maximum(1.0, np.maximum(np.abs(box.min), np.abs(box.max)))
    if len(points) != len(corners):
        v.fail(
            "vertices",
            f"expected {len(corners)} vertices (the corners of the "
            f"{len(box.names)}-axis box), got {len(points)}",
        )
    where: dict[int, int] = {}
    for i, p in enumerate(points):
        hits = [c for c in range(len(corners)) if np.all(np.abs(p - corners[c]) <= 1e-9 * scale)]
        if not hits:
            v.fail(
                f"vertices[{i}].scheduling",
                f"{_floats(p)} is not a corner of the box "
                f"min={_floats(box.min)} max={_floats(box.max)}",
            )
        c = hits[0]
        if c in where:
            v.fail(
                f"vertices[{i}].scheduling",
                f"corner {_floats(corners[c])} already given by vertices[{where[c]}]",
            )
        where[c] = i
    return [where[c] for c in range(len(corners))]


# ------------------------------------------------------------------- vertex models
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
    def parse(cls, v: _V, d, path: str, n_x: int, n_u: int) -> "UncertainEntry":
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


def _fit(v: _V, d, path: str) -> dict:
    v.mapping(d, path, (), extra_ok=True)
    out = {}
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
        d = {
            "scheduling": _floats(self.scheduling),
            "x0": _floats(self.x0),
            "u0": _floats(self.u0),
            "A": _rows(self.A),
            "B": _rows(self.B),
            "uncertain": [e.to_dict() for e in self.uncertain],
        }
        if self.fit:
            d["fit"] = {m: {k: float(x) for k, x in per.items()} for m, per in self.fit.items()}
        return d

    @classmethod
    def parse(cls, v: _V, d, i: int, n_x: int, n_u: int, n_p: int) -> "VertexModel":
        p = f"vertices[{i}]"
        v.mapping(d, p, ("scheduling", "x0", "u0", "A", "B"), ("uncertain", "fit"))
        unc = d.get("uncertain") or []
        if not isinstance(unc, list):
            v.fail(f"{p}.uncertain", f"expected a list, got {_kind(unc)}")
        entries = tuple(
            UncertainEntry.parse(v, e, f"{p}.uncertain[{k}]", n_x, n_u) for k, e in enumerate(unc)
        )
        seen = {}
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


class _StackedVertices:
    """Stacked views of per-vertex arrays in box order (the arrays of
    :class:`lpv_sysid.models.lpv.PolytopicModel`), shared by the models and gains files."""

    vertices: tuple

    def _stacked(self, name: str) -> np.ndarray:
        return np.stack([getattr(vx, name) for vx in self.vertices])

    @property
    def x0(self) -> np.ndarray:
        return self._stacked("x0")

    @property
    def u0(self) -> np.ndarray:
        return self._stacked("u0")


@dataclass(frozen=True)
class VertexModels(_StackedVertices):
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
            "time": _time_dict(self.ts),
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
        v = _V(label)
        lay = layout or Layout()
        v.mapping(
            d, "", ("format", "time", "states", "inputs", "scheduling", "vertices"), ("meta",)
        )
        if not isinstance(d["format"], str) or d["format"] not in MODELS_FORMATS:
            v.fail(
                "format",
                f"expected {MODELS_FORMAT!r} (or {MODELS_FORMAT_V1!r}), got {d['format']!r}",
            )
        ts = _time(v, d["time"])
        sn, su = _channels(v, d["states"], "states", lay.state_names, lay.state_units)
        inn, inu = _channels(v, d["inputs"], "inputs", lay.input_names, lay.input_units)
        box = SchedulingBox.parse(v, d["scheduling"], lay.scheduling_names)
        if not isinstance(d["vertices"], list):
            v.fail("vertices", f"expected a list, got {_kind(d['vertices'])}")
        vxs = [
            VertexModel.parse(v, e, i, len(sn), len(inn), len(box.names))
            for i, e in enumerate(d["vertices"])
        ]
        order = _order_vertices(v, [vx.scheduling for vx in vxs], box)
        meta = d.get("meta") or {}
        if not isinstance(meta, Mapping):
            v.fail("meta", f"expected a mapping, got {_kind(meta)}")
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
    def load(cls, path, layout: Optional[Layout] = QUADROTOR_LAYOUT) -> "VertexModels":
        path = Path(path)
        return cls.from_dict(load_yaml(path), layout, label=path.name)

    def save(self, path) -> str:
        """Write the file (validated first, written atomically); returns its SHA-256."""
        doc = self.to_dict()
        self.from_dict(doc, layout=None, label=Path(path).name)  # never write an invalid file
        _write_yaml(path, doc, Path(path).name)
        return sha256_file(path)


# ---------------------------------------------------------------------------- gains
@dataclass(frozen=True)
class GainVertex:
    """Gain at one scheduling corner: ``u = u0 + K (x - x0)`` (seed 0 Eq. 31).

    ``F_ff`` (optional, rows = ``feedforward.free_states`` then all inputs, columns =
    ``feedforward.accelerated_states``): the reference feedforward of
    :mod:`lpv_sysid.synthesis.feedforward`, ``(dx_ff, du_ff) = F_ff a`` with a = dv_d/dt.
    """

    scheduling: np.ndarray
    K: np.ndarray
    x0: np.ndarray
    u0: np.ndarray
    F_ff: Optional[np.ndarray] = None
    F_jerk: Optional[np.ndarray] = None

    def to_dict(self) -> dict:
        d = {
            "scheduling": _floats(self.scheduling),
            "K": _rows(self.K),
            "x0": _floats(self.x0),
            "u0": _floats(self.u0),
        }
        if self.F_ff is not None:
            d["F_ff"] = _rows(self.F_ff)
        if self.F_jerk is not None:
            d["F_jerk"] = _rows(self.F_jerk)
        return d

    @classmethod
    def parse(
        cls,
        v: _V,
        d,
        i: int,
        n_x: int,
        n_u: int,
        n_p: int,
        ff_shape: Optional[tuple] = None,
        jerk_shape: Optional[tuple] = None,
    ) -> "GainVertex":
        p = f"vertices[{i}]"
        v.mapping(d, p, ("scheduling", "K", "x0", "u0"), ("F_ff", "F_jerk"))
        mats = {}
        for key, shape, why in (
            ("F_ff", ff_shape, "'feedforward'"),
            ("F_jerk", jerk_shape, "'feedforward' with kinematic_states/rate_states"),
        ):
            mats[key] = None
            if key in d:
                if shape is None:
                    v.fail(f"{p}.{key}", f"given but the file has no top-level {why}")
                mats[key] = v.matrix(d[key], shape, f"{p}.{key}")
            elif shape is not None:
                v.fail(p, f"missing key {key!r} (the file declares {why}: every vertex needs it)")
        return cls(
            v.vector(d["scheduling"], n_p, f"{p}.scheduling"),
            v.matrix(d["K"], (n_u, n_x), f"{p}.K"),
            v.vector(d["x0"], n_x, f"{p}.x0"),
            v.vector(d["u0"], n_u, f"{p}.u0"),
            mats["F_ff"],
            mats["F_jerk"],
        )


@dataclass(frozen=True)
class FeedforwardSpec:
    """Top-level ``feedforward`` of gains.yaml: the layout of the per-vertex ``F_ff``
    (:class:`lpv_sysid.synthesis.feedforward.FeedforwardLayout`). Absent = no feedforward."""

    free_states: tuple
    accelerated_states: tuple
    held_states: tuple
    kinematic_states: tuple = ()  # jerk term (both non-empty): per-vertex F_jerk
    rate_states: tuple = ()

    @property
    def has_jerk(self) -> bool:
        return bool(self.kinematic_states) and bool(self.rate_states)

    def to_dict(self) -> dict:
        d = {
            "free_states": list(self.free_states),
            "accelerated_states": list(self.accelerated_states),
            "held_states": list(self.held_states),
        }
        if self.has_jerk:
            d["kinematic_states"] = list(self.kinematic_states)
            d["rate_states"] = list(self.rate_states)
        return d

    def shape(self, n_u: int) -> tuple:
        return (len(self.free_states) + n_u, len(self.accelerated_states))

    def jerk_shape(self, n_u: int) -> Optional[tuple]:
        if not self.has_jerk:
            return None
        return (len(self.free_states) + n_u + len(self.rate_states), len(self.accelerated_states))

    @classmethod
    def parse(
        cls, v: _V, d, state_names: tuple, n_u: int, n_p: int, path: str = "feedforward"
    ) -> "FeedforwardSpec":
        v.mapping(
            d,
            path,
            ("free_states", "accelerated_states", "held_states"),
            ("kinematic_states", "rate_states"),
        )
        if ("kinematic_states" in d) != ("rate_states" in d):
            v.fail(path, "kinematic_states and rate_states go together (the jerk term needs both)")
        got = {}
        for k in (
            "free_states",
            "accelerated_states",
            "held_states",
            "kinematic_states",
            "rate_states",
        ):
            if k not in d:
                got[k] = ()
                continue
            lst = d[k]
            if not isinstance(lst, list) or not lst:
                v.fail(
                    f"{path}.{k}", f"expected a non-empty list of state names, got {_kind(lst)}"
                )
            names = tuple(v.string(s, f"{path}.{k}[{j}]") for j, s in enumerate(lst))
            bad = [s for s in names if s not in state_names]
            if bad:
                v.fail(f"{path}.{k}", f"{bad} are not state names {list(state_names)}")
            if len(set(names)) != len(names):
                v.fail(f"{path}.{k}", f"duplicate names in {list(names)}")
            got[k] = names
        if len(got["accelerated_states"]) != n_p:
            v.fail(
                f"{path}.accelerated_states",
                f"expected {n_p} entries (one per scheduling axis), "
                f"got {len(got['accelerated_states'])}",
            )
        if set(got["free_states"]) & set(got["accelerated_states"]):
            v.fail(path, "a state cannot be both free and accelerated")
        if (
            len(got["accelerated_states"]) + len(got["held_states"])
            != len(got["free_states"]) + n_u
        ):
            v.fail(
                path,
                "the feedforward system must be square: accelerated + held rows = free states + inputs",
            )
        if not set(got["kinematic_states"]) <= set(got["free_states"]):
            v.fail(f"{path}.kinematic_states", "must be among the free states")
        return cls(
            got["free_states"],
            got["accelerated_states"],
            got["held_states"],
            got["kinematic_states"],
            got["rate_states"],
        )


@dataclass(frozen=True)
class DesignEnvelope:
    """``certificate.design``: the phase-2 signal the gains were designed for (written by
    ``lpv-sysid synthesize`` from the signals summary;
    :func:`lpv_sysid.signals.excitation.design_envelope`).

    The runtime bounds what it follows by it: ``reference_peak`` |v_d| per scheduling axis
    [m/s], ``reference_rate`` |dv_d/dt| [m/s^2] and ``reference_accel`` |d2v_d/dt2| [m/s^3]
    (Bernstein bounds of the band-limited table), ``knot_interval_s`` the table's sample
    interval (the played v_d is linear between samples), ``fade_s`` the shortest raised-cosine
    fade (excitation node ``ramp_s``) the rate and acceleration bounds include,
    ``excitation_peak`` |u_e| per excitation channel (normalised, Eq. 26), ``source`` where it
    came from."""

    reference_peak: tuple
    reference_rate: tuple
    reference_accel: tuple
    knot_interval_s: float
    fade_s: float
    excitation_peak: tuple
    source: str = ""

    KEYS = (
        "reference_peak",
        "reference_rate",
        "reference_accel",
        "knot_interval_s",
        "fade_s",
        "excitation_peak",
    )

    def to_dict(self) -> dict:
        return {
            "reference_peak": list(self.reference_peak),
            "reference_rate": list(self.reference_rate),
            "reference_accel": list(self.reference_accel),
            "knot_interval_s": float(self.knot_interval_s),
            "fade_s": float(self.fade_s),
            "excitation_peak": list(self.excitation_peak),
            "source": self.source,
        }

    @classmethod
    def parse(
        cls, v: _V, d, n_p: Optional[int], n_e: Optional[int], path: str = "certificate.design"
    ) -> "DesignEnvelope":
        v.mapping(d, path, cls.KEYS, ("source",))
        out = {}
        for key, n in (
            ("reference_peak", n_p),
            ("reference_rate", n_p),
            ("reference_accel", n_p),
            ("excitation_peak", n_e),
        ):
            vec = v.vector(d[key], n, f"{path}.{key}")
            if np.any(vec <= 0):
                v.fail(f"{path}.{key}", f"entries must be > 0, got {_floats(vec)}")
            out[key] = tuple(_floats(vec))
        knot = v.number(d["knot_interval_s"], f"{path}.knot_interval_s")
        if not knot > 0:
            v.fail(f"{path}.knot_interval_s", f"must be > 0, got {knot}")
        fade = v.number(d["fade_s"], f"{path}.fade_s")
        if not fade > 0:
            v.fail(f"{path}.fade_s", f"must be > 0, got {fade}")
        source = v.string(d.get("source", ""), f"{path}.source", nonempty=False)
        return cls(
            out["reference_peak"],
            out["reference_rate"],
            out["reference_accel"],
            knot,
            fade,
            out["excitation_peak"],
            source,
        )


#: ``certificate.certified_set.kind`` / ``.scheduling.variation`` (module docstring)
CERTIFIED_SET_KINDS = ("full_identified_box", "reduced_polytope")
SCHEDULING_VARIATIONS = ("frozen", "arbitrary", "rate_bounded")


@dataclass(frozen=True)
class Certificate:
    """What the synthesis proved (seed 0 Lemma 1) and for which models file.

    ``gains_sha256``: :meth:`GainSchedule.law_sha256` of the law that was certified (written
    once, by the tool that certified it); ``design``: the :class:`DesignEnvelope`."""

    lmi: str
    solver: str
    gamma_achieved: float
    min_margin: float
    models_sha256: str
    extra: dict = field(default_factory=dict)
    gains_sha256: Optional[str] = None
    design: Optional[DesignEnvelope] = None

    def to_dict(self) -> dict:
        d = {
            "lmi": self.lmi,
            "solver": self.solver,
            "gamma_achieved": float(self.gamma_achieved),
            "min_margin": float(self.min_margin),
            "models_sha256": self.models_sha256,
        }
        d.update(self.extra)
        if self.gains_sha256 is not None:
            d["gains_sha256"] = self.gains_sha256
        if self.design is not None:
            d["design"] = self.design.to_dict()
        return d

    @staticmethod
    def _sha(v: _V, x, path: str) -> str:
        sha = v.string(x, path)
        if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            v.fail(path, f"expected 64 lowercase hex digits, got {sha!r}")
        return sha

    @classmethod
    def parse(
        cls,
        v: _V,
        d,
        path: str = "certificate",
        n_p: Optional[int] = None,
        n_e: Optional[int] = None,
    ) -> "Certificate":
        req = ("lmi", "solver", "gamma_achieved", "min_margin", "models_sha256")
        own = req + ("gains_sha256", "design")
        v.mapping(d, path, req, extra_ok=True)
        sha = cls._sha(v, d["models_sha256"], f"{path}.models_sha256")
        g = v.number(d["gamma_achieved"], f"{path}.gamma_achieved")
        if g <= 0:
            v.fail(f"{path}.gamma_achieved", f"must be > 0, got {g}")
        gains_sha = (
            cls._sha(v, d["gains_sha256"], f"{path}.gains_sha256")
            if d.get("gains_sha256") is not None
            else None
        )
        design = (
            DesignEnvelope.parse(v, d["design"], n_p, n_e, f"{path}.design")
            if d.get("design") is not None
            else None
        )
        cs = d.get("certified_set")
        if cs is not None:
            v.mapping(
                cs, f"{path}.certified_set", ("kind", "statement", "scheduling"), extra_ok=True
            )
            if cs["kind"] not in CERTIFIED_SET_KINDS:
                v.fail(
                    f"{path}.certified_set.kind",
                    f"expected one of {CERTIFIED_SET_KINDS}, got {cs['kind']!r}",
                )
            v.mapping(
                cs["scheduling"], f"{path}.certified_set.scheduling", ("variation",), extra_ok=True
            )
            if cs["scheduling"]["variation"] not in SCHEDULING_VARIATIONS:
                v.fail(
                    f"{path}.certified_set.scheduling.variation",
                    f"expected one of {SCHEDULING_VARIATIONS}, got {cs['scheduling']['variation']!r}",
                )
        return cls(
            v.string(d["lmi"], f"{path}.lmi"),
            v.string(d["solver"], f"{path}.solver"),
            g,
            v.number(d["min_margin"], f"{path}.min_margin"),
            sha,
            {k: d[k] for k in d if k not in own},
            gains_sha,
            design,
        )


@dataclass(frozen=True)
class GainSchedule(_StackedVertices):
    """Contents of ``gains.yaml``; ``vertices`` in box order."""

    state_names: tuple
    state_units: tuple
    input_names: tuple
    input_units: tuple
    scheduling: SchedulingBox
    vertices: tuple
    R: np.ndarray
    Q: np.ndarray
    gamma: float
    certificate: Certificate
    ts: Optional[float] = None
    feedforward: Optional[FeedforwardSpec] = None

    @property
    def F_ff(self) -> Optional[np.ndarray]:
        """Stacked feedforward matrices (N, n_free + m, p) in box order, or None."""
        if self.feedforward is None:
            return None
        return self._stacked("F_ff")

    @property
    def F_jerk(self) -> Optional[np.ndarray]:
        """Stacked jerk-term matrices (N, n_free + m + n_rate, p) in box order, or None."""
        if self.feedforward is None or not self.feedforward.has_jerk:
            return None
        return self._stacked("F_jerk")

    @property
    def K(self) -> np.ndarray:
        """Stacked gains (N, m, n) in box order."""
        return self._stacked("K")

    def law_sha256(self) -> str:
        """SHA-256 of the law the runtime flies: channel and scheduling names, the box, the
        time base, per vertex (box order) K, x0, u0 (and F_ff, F_jerk with their layout),
        R, Q and gamma, as float64 bytes (a YAML round trip keeps every bit). The certifying
        tool writes it to ``certificate.gains_sha256`` (:func:`certify_law`); the runtime
        refuses a file whose law no longer hashes to it."""
        h = hashlib.sha256(b"lpv_sysid/gains-law@1")

        def put(tag: str, a) -> None:
            a = np.ascontiguousarray(np.asarray(a, dtype="<f8"))
            h.update(f"|{tag}{a.shape}|".encode())
            h.update(a.tobytes())

        h.update(repr((self.state_names, self.input_names, self.scheduling.names)).encode())
        put("min", self.scheduling.min)
        put("max", self.scheduling.max)
        put("ts", [] if self.ts is None else [self.ts])
        for name in ("K", "x0", "u0"):
            put(name, getattr(self, name))
        put("R", self.R)
        put("Q", self.Q)
        put("gamma", [self.gamma])
        if self.feedforward is not None:
            h.update(repr(sorted(self.feedforward.to_dict().items())).encode())
            put("F_ff", self.F_ff)
            if self.F_jerk is not None:
                put("F_jerk", self.F_jerk)
        return h.hexdigest()

    def check_law_sha256(self, label: str = "gains.yaml") -> None:
        """ConfigError unless ``certificate.gains_sha256`` is present and equals
        :meth:`law_sha256` (the gains flown are the gains that were certified)."""
        v = _V(label)
        got = self.certificate.gains_sha256
        if got is None:
            v.fail(
                "certificate.gains_sha256",
                "missing: the file does not record which gains "
                "were certified (written before this check existed); re-run `lpv-sysid "
                "synthesize` to regenerate the gains and their certificate",
            )
        if got != self.law_sha256():
            v.fail(
                "certificate.gains_sha256",
                f"{got} does not match the gains in the file "
                f"(sha256 {self.law_sha256()}): K, x0, u0, R, Q, gamma or the feedforward "
                "were changed after certification; re-run `lpv-sysid synthesize` (and "
                "`lpv-sysid verify`) instead of editing gains",
            )

    def to_dict(self) -> dict:
        d = {"format": GAINS_FORMAT}
        if self.ts is not None:
            d["time"] = _time_dict(self.ts)
        d.update(
            {
                "states": [
                    {"name": n, "unit": u} for n, u in zip(self.state_names, self.state_units)
                ],
                "inputs": [
                    {"name": n, "unit": u} for n, u in zip(self.input_names, self.input_units)
                ],
                "scheduling": self.scheduling.to_dict(),
                "vertices": [vx.to_dict() for vx in self.vertices],
                "R": _rows(self.R),
                "Q": _rows(self.Q),
                "gamma": float(self.gamma),
                "certificate": self.certificate.to_dict(),
            }
        )
        if self.feedforward is not None:
            d["feedforward"] = self.feedforward.to_dict()
        return d

    @classmethod
    def from_dict(
        cls, d, layout: Optional[Layout] = QUADROTOR_LAYOUT, label: str = "gains.yaml"
    ) -> "GainSchedule":
        v = _V(label)
        lay = layout or Layout()
        v.mapping(
            d,
            "",
            (
                "format",
                "states",
                "inputs",
                "scheduling",
                "vertices",
                "R",
                "Q",
                "gamma",
                "certificate",
            ),
            ("time", "feedforward"),
        )
        if d["format"] != GAINS_FORMAT:
            v.fail("format", f"expected {GAINS_FORMAT!r}, got {d['format']!r}")
        ts = _time(v, d["time"]) if "time" in d else None
        sn, su = _channels(v, d["states"], "states", lay.state_names, lay.state_units)
        inn, inu = _channels(v, d["inputs"], "inputs", lay.input_names, lay.input_units)
        box = SchedulingBox.parse(v, d["scheduling"], lay.scheduling_names)
        n_x, n_u, n_p = len(sn), len(inn), len(box.names)
        if not isinstance(d["vertices"], list):
            v.fail("vertices", f"expected a list, got {_kind(d['vertices'])}")
        ff = None
        if d.get("feedforward") is not None:
            ff = FeedforwardSpec.parse(v, d["feedforward"], sn, n_u, n_p)
        ff_shape = None if ff is None else ff.shape(n_u)
        jerk_shape = None if ff is None else ff.jerk_shape(n_u)
        vxs = [
            GainVertex.parse(v, e, i, n_x, n_u, n_p, ff_shape, jerk_shape)
            for i, e in enumerate(d["vertices"])
        ]
        order = _order_vertices(v, [vx.scheduling for vx in vxs], box)
        R = v.matrix(d["R"], (n_u, n_u), "R")
        Q = v.matrix(d["Q"], (n_p, n_p), "Q")
        if abs(np.linalg.det(Q)) < 1e-12 * max(1.0, np.abs(Q).max()) ** n_p:
            v.fail("Q", "must be invertible (z = Q^-1 (v - v_d), seed 0 Eq. 28)")
        gamma = v.number(d["gamma"], "gamma")
        if gamma <= 0:
            v.fail("gamma", f"must be > 0, got {gamma}")
        cert = Certificate.parse(v, d["certificate"], n_p=n_p, n_e=R.shape[1])
        if cert.gamma_achieved > gamma * (1 + 1e-6):
            v.fail("certificate.gamma_achieved", f"{cert.gamma_achieved} exceeds gamma = {gamma}")
        return cls(sn, su, inn, inu, box, tuple(vxs[k] for k in order), R, Q, gamma, cert, ts, ff)

    @classmethod
    def load(
        cls, path, models_path=None, layout: Optional[Layout] = QUADROTOR_LAYOUT
    ) -> "GainSchedule":
        """Load and validate; with ``models_path`` also check it against the models file
        (:meth:`check_models`)."""
        path = Path(path)
        gs = cls.from_dict(load_yaml(path), layout, label=path.name)
        if models_path is not None:
            models = VertexModels.load(models_path, layout)
            gs.check_models(
                models,
                sha256_file(models_path),
                label=path.name,
                models_label=Path(models_path).name,
            )
        return gs

    def check_models(
        self,
        models: VertexModels,
        models_sha256: Optional[str] = None,
        label: str = "gains.yaml",
        models_label: str = "vertex_models.yaml",
        rtol: float = 1e-9,
    ) -> None:
        """Refuse gains synthesised for other models: names, units, box, time base, vertex
        equilibria and (when given) the models file's SHA-256."""
        v = _V(label)
        for what, mine, theirs in (
            (
                "states",
                (self.state_names, self.state_units),
                (models.state_names, models.state_units),
            ),
            (
                "inputs",
                (self.input_names, self.input_units),
                (models.input_names, models.input_units),
            ),
        ):
            if mine != theirs:
                v.fail(
                    what,
                    f"names/units {list(zip(*mine))} differ from {models_label} "
                    f"{list(zip(*theirs))}",
                )
        if not self.scheduling.same_as(models.scheduling):
            v.fail(
                "scheduling",
                f"box {self.scheduling.to_dict()} differs from {models_label} "
                f"{models.scheduling.to_dict()}",
            )
        if self.ts != models.ts:
            v.fail(
                "time",
                f"{_time_dict(self.ts)!r} differs from {models_label} {_time_dict(models.ts)!r}",
            )
        for i, (g, m) in enumerate(zip(self.vertices, models.vertices)):
            for name in ("x0", "u0"):
                a, b = getattr(g, name), getattr(m, name)
                if not np.allclose(a, b, rtol=rtol, atol=rtol):
                    v.fail(
                        f"vertices[{i}].{name}",
                        f"differs from {models_label} vertices[{i}].{name} "
                        f"(max |diff| {np.max(np.abs(a - b)):.3g})",
                    )
        if models_sha256 is not None and models_sha256 != self.certificate.models_sha256:
            v.fail(
                "certificate.models_sha256",
                f"{self.certificate.models_sha256} does not match "
                f"{models_label} (sha256 {models_sha256})",
            )

    def save(self, path) -> None:
        doc = self.to_dict()
        self.from_dict(doc, layout=None, label=Path(path).name)  # never write an invalid file
        _write_yaml(path, doc, Path(path).name)


def certify_law(doc: dict, layout: Optional[Layout] = None, label: str = "gains.yaml") -> dict:
    """``doc`` (a gains.yaml mapping) with ``certificate.gains_sha256`` set to the
    :meth:`GainSchedule.law_sha256` of the law it holds. Called only by the tool that
    certified that law (``lpv-sysid synthesize``; the LQR test-law writer of the tests),
    never by a loader or editor: the hash records what was certified."""
    gs = GainSchedule.from_dict(doc, layout, label)
    return {**doc, "certificate": {**doc["certificate"], "gains_sha256": gs.law_sha256()}}


#: arrays of the certificate sidecar holding the certified Eq. (23) systems (A_ij, B_ij):
#: ``A_sys`` (N, M, n, n), ``B_sys`` (N, M, n, m), NaN past ``M_sys[i]`` systems at vertex i
SYSTEMS_ARRAYS = ("A_sys", "B_sys", "M_sys")


def systems_arrays(systems: Sequence[Sequence[tuple]]) -> dict:
    """The :data:`SYSTEMS_ARRAYS` of per-vertex lists of ``(A, B)`` (the polytope the
    certificate covers, ``PolytopicModel.systems``), for the sidecar writer."""
    N = len(systems)
    Ms = np.array([len(s) for s in systems], dtype=np.int64)
    n, m = np.asarray(systems[0][0][1]).shape
    A = np.full((N, int(Ms.max()), n, n), np.nan)
    B = np.full((N, int(Ms.max()), n, m), np.nan)
    for i, lst in enumerate(systems):
        for j, (a, b) in enumerate(lst):
            A[i, j], B[i, j] = a, b
    return {"A_sys": A, "B_sys": B, "M_sys": Ms}


def load_certified_systems(
    gains_path, certificate: Certificate, n_x: int, n_u: int, label: Optional[str] = None
) -> list:
    """Per-vertex lists of the certified ``(A_ij, B_ij)`` from the sidecar named in
    ``certificate.sidecar`` (``{file, sha256}``, next to the gains file); ConfigError when
    the entry, the file, its sha256 or the :data:`SYSTEMS_ARRAYS` are missing or wrong."""
    from lpv_sysid.io.safe_open import read_npz

    gains_path = Path(gains_path)
    v = _V(label or gains_path.name)
    side = certificate.extra.get("sidecar")
    if (
        not isinstance(side, Mapping)
        or not isinstance(side.get("file"), str)
        or not isinstance(side.get("sha256"), str)
    ):
        v.fail(
            "certificate.sidecar",
            "missing {file, sha256}: the certified systems cannot be "
            "re-checked; re-run `lpv-sysid synthesize`",
        )
    path = gains_path.parent / side["file"]
    if not path.exists():
        v.fail("certificate.sidecar", f"sidecar {path} not found (copy it next to the gains file)")
    sha = sha256_file(path)
    if sha != side["sha256"]:
        v.fail(
            "certificate.sidecar.sha256",
            f"{side['sha256']} does not match {path.name} "
            f"(sha256 {sha}): the sidecar was changed or belongs to other gains",
        )
    d = read_npz(path, path.name)
    missing = [k for k in SYSTEMS_ARRAYS if k not in d]
    if missing:
        v.fail(
            "certificate.sidecar",
            f"{path.name} has no certified systems {missing} "
            "(written before this check existed); re-run `lpv-sysid synthesize`",
        )
    A, B, Ms = d["A_sys"], d["B_sys"], d["M_sys"]
    N = len(Ms)
    if (
        A.ndim != 4
        or B.ndim != 4
        or A.shape[:2] != B.shape[:2]
        or A.shape[0] != N
        or A.shape[2:] != (n_x, n_x)
        or B.shape[2:] != (n_x, n_u)
        or Ms.ndim != 1
        or np.any(Ms < 1)
        or np.any(Ms > A.shape[1])
    ):
        v.fail(
            "certificate.sidecar",
            f"{path.name}: certified systems have shapes A {A.shape}, "
            f"B {B.shape}, M {Ms.shape}; expected (N, M, {n_x}, {n_x}), (N, M, {n_x}, {n_u})",
        )
    out = []
    for i in range(N):
        a, b = A[i, : int(Ms[i])], B[i, : int(Ms[i])]
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            v.fail(
                "certificate.sidecar",
                f"{path.name}: certified systems of vertex {i} are not finite",
            )
        out.append([(a[j], b[j]) for j in range(int(Ms[i]))])
    return out
