"""What ``vertex_models.yaml`` and ``gains.yaml`` share: channel layout, time base, scheduling box.

* :class:`Layout`: the expected channel names and units (:data:`QUADROTOR_LAYOUT` from
  :mod:`lpv_sysid.models.quadrotor`, or none: any names, shapes from the lists);
  :func:`layout_of` picks the quadrotor layout for a document that names the quadrotor's states;
* ``states`` / ``inputs``: lists of ``{name, unit}`` (:func:`parse_channels`);
* ``time``: ``continuous`` or ``{discrete: Ts}`` (:func:`parse_time`);
* ``scheduling``: the box of seed 0 Eq. (20), ``names``, ``min`` < ``max``
  (:class:`SchedulingBox`);
* ``vertices``: exactly the 2^p corners of the box, each once, in any order; stored and
  written in the box order of :func:`lpv_sysid.models.lpv.box_vertices`
  (``itertools.product`` over ``(min_k, max_k)``, first axis slowest) (:func:`order_vertices`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Mapping, Optional

import numpy as np

from lpv_sysid.io.formats.field_checker import FieldChecker, floats, kind_of


@dataclass(frozen=True)
class Layout:
    """Expected channel names and units; ``None`` fields are not checked."""

    state_names: Optional[tuple] = None
    state_units: Optional[tuple] = None
    input_names: Optional[tuple] = None
    input_units: Optional[tuple] = None
    scheduling_names: Optional[tuple] = None


def _quadrotor_layout() -> Layout:
    # The single place the expected names live: models/quadrotor/model.py (DESIGN.md state order).
    from lpv_sysid.models import quadrotor as qr

    return Layout(
        tuple(qr.STATE_NAMES),
        tuple(qr.STATE_UNITS),
        tuple(qr.INPUT_NAMES),
        tuple(qr.INPUT_UNITS),
        tuple(qr.SCHEDULING_NAMES),
    )


QUADROTOR_LAYOUT = _quadrotor_layout()


def layout_of(doc: Any) -> Optional[Layout]:
    """:data:`QUADROTOR_LAYOUT` (names and units strictly checked) for a document whose
    ``states`` are named like the quadrotor's, else ``None`` (a generic plant: shapes,
    finiteness and the box are still checked). Looks at the parsed document only."""
    states = doc.get("states") if isinstance(doc, Mapping) else None
    if not isinstance(states, list):
        return QUADROTOR_LAYOUT
    names = tuple(e.get("name") if isinstance(e, Mapping) else e for e in states)
    return QUADROTOR_LAYOUT if names == QUADROTOR_LAYOUT.state_names else None


def parse_channels(v: FieldChecker, d, path: str, names: Optional[tuple], units: Optional[tuple]):
    if not isinstance(d, list) or not d:
        v.fail(path, f"expected a non-empty list of {{name, unit}}, got {kind_of(d)}")
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


def parse_time(v: FieldChecker, d, path: str = "time") -> Optional[float]:
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


def time_dict(ts: Optional[float]):
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
        return {"names": list(self.names), "min": floats(self.min), "max": floats(self.max)}

    @classmethod
    def parse(
        cls, v: FieldChecker, d, names: Optional[tuple], path: str = "scheduling"
    ) -> "SchedulingBox":
        v.mapping(d, path, ("names", "min", "max"))
        if not isinstance(d["names"], list) or not d["names"]:
            v.fail(
                f"{path}.names", f"expected a non-empty list of names, got {kind_of(d['names'])}"
            )
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


def order_vertices(v: FieldChecker, points: list, box: SchedulingBox) -> list[int]:
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
                f"{floats(p)} is not a corner of the box "
                f"min={floats(box.min)} max={floats(box.max)}",
            )
        c = hits[0]
        if c in where:
            v.fail(
                f"vertices[{i}].scheduling",
                f"corner {floats(corners[c])} already given by vertices[{where[c]}]",
            )
        where[c] = i
    return [where[c] for c in range(len(corners))]


class StackedVertices:
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
