"""One entry of ``vertices`` in ``gains.yaml`` (:class:`GainVertex`): the gain at a
scheduling corner, its equilibrium and the optional feedforward matrices, strictly
validated (the file: :mod:`lpv_sysid.io.formats.gains`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from lpv_sysid.io.formats.field_checker import FieldChecker, floats, rows


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
            "scheduling": floats(self.scheduling),
            "K": rows(self.K),
            "x0": floats(self.x0),
            "u0": floats(self.u0),
        }
        if self.F_ff is not None:
            d["F_ff"] = rows(self.F_ff)
        if self.F_jerk is not None:
            d["F_jerk"] = rows(self.F_jerk)
        return d

    @classmethod
    def parse(
        cls,
        v: FieldChecker,
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
        mats: dict[str, Optional[np.ndarray]] = {}
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
