"""The polytopic LPV model object (:class:`PolytopicModel`, :class:`ScheduledLpv`, seed 0
Eqs. 20-23); the method is the :mod:`lpv_sysid.models.lpv` docstring."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Iterable, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.lpv.box import (
    box_vertices,
    check_box,
    multilinear_weight_gradient,
    multilinear_weights,
)
from lpv_sysid.models.lpv.element_box import ElementBox
from lpv_sysid.models.lpv.uncertainty import (
    MAX_CORNERS_DEFAULT,
    CommonInputSet,
    UncertainElement,
    input_corners,
    input_hull,
    product_systems,
    uncertainty_vertices,
)

log = logging.getLogger(__name__)


@dataclass
class PolytopicModel:
    """Nominal vertex systems, equilibria and nested uncertainty vertices (Eqs. 20-23).

    ``A`` (N, n, n), ``B`` (N, n, m), ``x0`` (N, n), ``u0`` (N, m) in the vertex order of
    :func:`box_vertices`; ``systems[i]`` is the list of (A_i^j, B_i^j) of Eq. (23) (defaults to
    the nominal vertex only). ``ts`` is None for continuous time, else the sample time.
    """

    vmin: np.ndarray
    vmax: np.ndarray
    A: np.ndarray
    B: np.ndarray
    x0: np.ndarray
    u0: np.ndarray
    systems: list = field(default_factory=list)
    ts: Optional[float] = None
    state_names: tuple = ()
    input_names: tuple = ()
    scheduling_names: tuple = ()
    #: set when the input matrices of ``systems`` are the common corners B^b in product order
    #: (j = a * M_B + b, see :func:`product_systems`); None = per-vertex B_i^j (vertices only).
    common_input: Optional[CommonInputSet] = None
    #: set when the certified set is the whole element box (``systems`` then holds a finite
    #: sample of it, :meth:`ElementBox.sample_systems`); None = the polytope ``systems`` itself.
    box: Optional[ElementBox] = None

    def __post_init__(self) -> None:
        self.vmin, self.vmax = check_box(self.vmin, self.vmax)
        p = self.vmin.size
        N = 2**p
        self.A = np.asarray(self.A, dtype=float)
        self.B = np.asarray(self.B, dtype=float)
        if self.A.ndim != 3 or self.A.shape[0] != N or self.A.shape[1] != self.A.shape[2]:
            raise ConfigError(
                f"A must have shape ({N}, n, n) for a {p}-axis box, got {self.A.shape}"
            )
        n = self.A.shape[1]
        if self.B.ndim != 3 or self.B.shape[:2] != (N, n):
            raise ConfigError(f"B must have shape ({N}, {n}, m), got {self.B.shape}")
        m = self.B.shape[2]
        self.x0 = np.zeros((N, n)) if self.x0 is None else np.asarray(self.x0, dtype=float)
        self.u0 = np.zeros((N, m)) if self.u0 is None else np.asarray(self.u0, dtype=float)
        if self.x0.shape != (N, n):
            raise ConfigError(f"x0 must have shape ({N}, {n}), got {self.x0.shape}")
        if self.u0.shape != (N, m):
            raise ConfigError(f"u0 must have shape ({N}, {m}), got {self.u0.shape}")
        for name in ("A", "B", "x0", "u0"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ConfigError(f"{name} contains NaN/inf")
        if not self.systems:
            self.systems = [[(self.A[i], self.B[i])] for i in range(N)]
        if len(self.systems) != N:
            raise ConfigError(
                f"systems: need one list of uncertainty vertices per scheduling vertex ({N}), "
                f"got {len(self.systems)}"
            )
        for i, lst in enumerate(self.systems):
            if len(lst) == 0:
                raise ConfigError(f"systems[{i}] is empty")
            for j, (Aj, Bj) in enumerate(lst):
                if np.shape(Aj) != (n, n) or np.shape(Bj) != (n, m):
                    raise ConfigError(
                        f"systems[{i}][{j}]: shapes {np.shape(Aj)}, {np.shape(Bj)} "
                        f"!= ({n},{n}), ({n},{m})"
                    )
                if not (np.all(np.isfinite(Aj)) and np.all(np.isfinite(Bj))):
                    raise ConfigError(f"systems[{i}][{j}] contains NaN/inf")
        if self.common_input is not None:
            MB = self.common_input.M
            if np.shape(self.common_input.corners)[1:] != (n, m) or MB == 0:
                raise ConfigError(
                    f"common_input.corners must have shape (M_B, {n}, {m}), "
                    f"got {np.shape(self.common_input.corners)}"
                )
            bad = [i for i, lst in enumerate(self.systems) if len(lst) % MB]
            if bad:
                raise ConfigError(
                    f"common_input: systems of vertices {bad} are not a product with the "
                    f"M_B = {MB} input corners"
                )
        if self.ts is not None and not (np.isfinite(self.ts) and self.ts > 0):
            raise ConfigError(f"sample time must be > 0, got {self.ts!r}")
        if self.box is not None and (self.box.N != N or self.box.n != n or self.box.m != m):
            raise ConfigError(
                f"box: {self.box.N} vertices, {self.box.n} states, {self.box.m} inputs do not "
                "match "
                f"the model ({N}, {n}, {m})"
            )

    # sizes
    @property
    def n_vertices(self) -> int:
        return self.A.shape[0]

    @property
    def n_x(self) -> int:
        return self.A.shape[1]

    @property
    def n_u(self) -> int:
        return self.B.shape[2]

    @property
    def input_structure(self) -> dict:
        """{"B": "common" | "per_vertex", "M": [M_i], "M_A": [M_A,i], "M_B": M_B} (certificate
        entry)."""
        M = [len(lst) for lst in self.systems]
        if self.box is not None:
            return {
                "B": "common",
                "M": M,
                "M_A": M,
                "M_B": 1,
                "B_method": "element box",
                "p": self.box.p,
            }
        if self.common_input is None:
            return {"B": "per_vertex", "M": M, "M_A": M, "M_B": 1}
        MB = self.common_input.M
        return {
            "B": "common",
            "M": M,
            "M_A": [k // MB for k in M],
            "M_B": MB,
            "B_method": self.common_input.method,
        }

    @property
    def vertices(self) -> np.ndarray:
        return box_vertices(self.vmin, self.vmax)

    @classmethod
    def from_uncertain_elements(
        cls,
        vmin,
        vmax,
        A,
        B,
        x0,
        u0,
        elements: Sequence[Sequence[UncertainElement]],
        max_corners: int = MAX_CORNERS_DEFAULT,
        **kw,
    ) -> "PolytopicModel":
        """Build the nested polytope of Eq. (23) by corner enumeration per vertex."""
        A = np.asarray(A, dtype=float)
        B = np.asarray(B, dtype=float)
        if len(elements) != A.shape[0]:
            raise ConfigError(
                f"need one list of uncertain elements per vertex ({A.shape[0]}), got "
                f"{len(elements)}"
            )
        systems = [
            uncertainty_vertices(A[i], B[i], elements[i], max_corners) for i in range(A.shape[0])
        ]
        return cls(vmin=vmin, vmax=vmax, A=A, B=B, x0=x0, u0=u0, systems=systems, **kw)

    @classmethod
    def from_common_input(
        cls,
        vmin,
        vmax,
        A,
        B,
        x0,
        u0,
        elements: Sequence[Sequence[UncertainElement]],
        max_corners: int = MAX_CORNERS_DEFAULT,
        **kw,
    ) -> "PolytopicModel":
        """Eq. (23) with a common input set: per-vertex A corners (the A elements of
        ``elements[i]``) times the corners of the B hull (:func:`input_hull`), docstring of
        :mod:`lpv_sysid.models.lpv.uncertainty`."""
        A = np.asarray(A, dtype=float)
        B = np.asarray(B, dtype=float)
        if len(elements) != A.shape[0]:
            raise ConfigError(
                f"need one list of uncertain elements per vertex ({A.shape[0]}), got "
                f"{len(elements)}"
            )
        base, hull, nlo, nhi = input_hull(B, elements)
        common = CommonInputSet(
            input_corners(base, hull, max_corners), tuple(hull), nlo, nhi, "box"
        )
        a_corners = [
            [
                a
                for a, _ in uncertainty_vertices(
                    A[i],
                    B[i],
                    [e for e in elements[i] if e.matrix == "A"],
                    max(1, max_corners // common.M),
                )
            ]
            for i in range(A.shape[0])
        ]
        return cls(
            vmin=vmin,
            vmax=vmax,
            A=A,
            B=B,
            x0=x0,
            u0=u0,
            systems=product_systems(a_corners, common),
            common_input=common,
            **kw,
        )

    @classmethod
    def from_vertex_systems(
        cls, vmin, vmax, uncertain_vertices: Sequence, x0, u0, **kw
    ) -> "PolytopicModel":
        """Build from per-vertex objects with ``A``, ``B`` and ``systems`` (the explicit list of
        Eq. (23) systems, e.g. :class:`lpv_sysid.ident.vertex.uncertainty.UncertainVertex`)."""
        return cls(
            vmin=vmin,
            vmax=vmax,
            A=np.array([uv.A for uv in uncertain_vertices]),
            B=np.array([uv.B for uv in uncertain_vertices]),
            x0=x0,
            u0=u0,
            systems=[
                [(np.asarray(a), np.asarray(b)) for a, b in uv.systems]
                for uv in uncertain_vertices
            ],
            **kw,
        )

    # interpolation (seed 0 Eq. 21, Eq. 31, Eq. 34)
    def weights(self, v_d) -> tuple[np.ndarray, bool]:
        return multilinear_weights(v_d, self.vmin, self.vmax)

    def interpolate(self, stack: np.ndarray, v_d) -> np.ndarray:
        """sum_i alpha_i(v_d) stack[i] for a vertex-stacked array (N, ...)."""
        alpha, _ = self.weights(v_d)
        return np.tensordot(alpha, np.asarray(stack, dtype=float), axes=1)

    def A_at(self, v_d) -> np.ndarray:
        return self.interpolate(self.A, v_d)

    def B_at(self, v_d) -> np.ndarray:
        return self.interpolate(self.B, v_d)

    def x0_at(self, v_d) -> np.ndarray:
        return self.interpolate(self.x0, v_d)

    def u0_at(self, v_d) -> np.ndarray:
        return self.interpolate(self.u0, v_d)

    def dx0_dvd(self, v_d) -> np.ndarray:
        """d x0 / d v_d of seed 0 Eq. (34), shape (n, p): sum_i x0_i (d alpha_i / d v_d)^T."""
        grad = multilinear_weight_gradient(v_d, self.vmin, self.vmax)
        return self.x0.T @ grad


class ScheduledLpv:
    """Nominal LPV model plus vertex gains, evaluated at v_d.

    Implements the ``ScheduledModel`` protocol of :mod:`lpv_sysid.sim.closed_loop`
    (A, B, K, x0, u0, dx0_dvd at a scheduling point), K(v_d) = sum alpha_i K_i (Eq. 31).
    """

    def __init__(self, model: PolytopicModel, K: np.ndarray) -> None:
        K = np.asarray(K, dtype=float)
        if K.shape != (model.n_vertices, model.n_u, model.n_x):
            raise ConfigError(
                f"K must have shape ({model.n_vertices}, {model.n_u}, {model.n_x}), got {K.shape}"
            )
        self.model = model
        self.Kv = K

    def A(self, v_d):
        return self.model.A_at(v_d)

    def B(self, v_d):
        return self.model.B_at(v_d)

    def K(self, v_d):
        return self.model.interpolate(self.Kv, v_d)

    def x0(self, v_d):
        return self.model.x0_at(v_d)

    def u0(self, v_d):
        return self.model.u0_at(v_d)

    def dx0_dvd(self, v_d):
        return self.model.dx0_dvd(v_d)


def iter_systems(model: PolytopicModel) -> Iterable[tuple[int, int, np.ndarray, np.ndarray]]:
    """(i, j, A_i^j, B_i^j) over the nested polytope of Eq. (23)."""
    for i, lst in enumerate(model.systems):
        for j, (Aj, Bj) in enumerate(lst):
            yield i, j, np.asarray(Aj, dtype=float), np.asarray(Bj, dtype=float)


def common_input_deviation(model: PolytopicModel, M_B: int) -> tuple[float, float]:
    """How far ``model.systems`` is from the common-input product structure with M_B corners.

    Returns (dB, dA): dB = max |B_i^(a,b) - B_0^(0,b)| over all i, a, b (B^b identical across
    scheduling vertices and A-corners), dA = max |A_i^(a,b) - A_i^(a,0)| (A part independent of b).
    inf when a vertex's M_i is not a multiple of M_B. Pure numpy, independent of
    :class:`CommonInputSet` (used by the verifier).
    """
    if M_B < 1 or any(len(lst) % M_B for lst in model.systems):
        return float("inf"), float("inf")
    ref = [np.asarray(model.systems[0][b][1], dtype=float) for b in range(M_B)]
    dB = dA = 0.0
    for lst in model.systems:
        for j, (Aj, Bj) in enumerate(lst):
            a, b = divmod(j, M_B)
            dB = max(dB, float(np.max(np.abs(np.asarray(Bj, dtype=float) - ref[b]))))
            dA = max(
                dA,
                float(
                    np.max(
                        np.abs(
                            np.asarray(Aj, dtype=float) - np.asarray(lst[a * M_B][0], dtype=float)
                        )
                    )
                ),
            )
    return dB, dA
