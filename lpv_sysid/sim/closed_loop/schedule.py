"""The scheduled quantities of the LPV closed loop (seed 0 Eqs. 21, 31, 34) at a point v_d:
the :class:`ScheduledModel` protocol and its fast evaluation (weights without validation, the
last point cached)."""

from __future__ import annotations

from typing import Any, Optional, Protocol, cast

import numpy as np

from lpv_sysid.errors import ConfigError


class ScheduledModel(Protocol):
    """Nominal polytopic LPV model plus LPV gains, evaluated at a scheduling point v_d (3,)."""

    def A(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_x, n_x), Eq. (21)
    def B(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_x, n_u), B_c of Eq. (19)
    def K(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_u, n_x), Eq. (31)
    def x0(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_x,)
    def u0(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_u,)
    def dx0_dvd(self, v_d: np.ndarray) -> np.ndarray: ...  # (n_x, 3), Eq. (34)


def fast_weights(v_d: np.ndarray, vmin: np.ndarray, vmax: np.ndarray) -> np.ndarray:
    """alpha(v_d) of seed 0 Eq. (21), clamped to the box, in the vertex order of
    ``models.lpv.box_vertices`` -- the values of ``models.lpv.multilinear_weights`` without its
    input validation and np.kron (which dominated the RK4 loop: 3 kron calls per point)."""
    t = np.clip((np.asarray(v_d, dtype=float) - vmin) / (vmax - vmin), 0.0, 1.0)
    alpha = np.ones(1)
    for tk in t.tolist():
        alpha = np.outer(alpha, (1.0 - tk, tk)).ravel()  # first axis slowest, as kron
    return alpha


class LastPointCache:
    """Wraps a ScheduledModel and remembers its values at the last scheduling point.

    Within one RK step the stages share v_d (RK4 stages 2-3, the law and the right-hand side
    all ask for A, B, K, x0, u0 at the same point), so this halves to quarters the number of
    multilinear interpolations without changing any value.
    """

    _NAMES = ("A", "B", "K", "x0", "u0", "dx0_dvd")

    def __init__(self, model: ScheduledModel) -> None:
        self.model = model
        self._cache: dict[str, tuple[bytes, np.ndarray]] = {}

    def _get(self, name: str, v_d: np.ndarray) -> np.ndarray:
        key = np.asarray(v_d, dtype=float).tobytes()
        hit = self._cache.get(name)
        if hit is not None and hit[0] == key:
            return hit[1]
        stacks = vertex_stacks(self.model)
        if stacks is not None and name != "dx0_dvd":
            # one weight evaluation for all interpolated quantities at this point (Eq. 21, 31)
            w = self._cache.get("_alpha")
            if w is None or w[0] != key:
                pm = cast(Any, self.model).model  # a ScheduledLpv (vertex_stacks found it)
                if not np.all(np.isfinite(v_d)):
                    raise ConfigError(
                        f"scheduling point contains NaN/inf: {np.asarray(v_d).tolist()}"
                    )
                w = (key, fast_weights(v_d, pm.vmin, pm.vmax))
                self._cache["_alpha"] = w
            val = np.tensordot(w[1], stacks[name], axes=1)
        else:
            val = np.asarray(getattr(self.model, name)(v_d), dtype=float)
        self._cache[name] = (key, val)
        return val

    def A(self, v_d):
        return self._get("A", v_d)

    def B(self, v_d):
        return self._get("B", v_d)

    def K(self, v_d):
        return self._get("K", v_d)

    def x0(self, v_d):
        return self._get("x0", v_d)

    def u0(self, v_d):
        return self._get("u0", v_d)

    def dx0_dvd(self, v_d):
        return self._get("dx0_dvd", v_d)


def vertex_stacks(model: Any) -> Optional[dict[str, np.ndarray]]:
    """Vertex stacks of a :class:`lpv_sysid.models.lpv.ScheduledLpv` (else None)."""
    pm, Kv = getattr(model, "model", None), getattr(model, "Kv", None)
    if pm is None or Kv is None or not hasattr(pm, "weights"):
        return None
    return {"A": pm.A, "B": pm.B, "K": Kv, "x0": pm.x0, "u0": pm.u0}
