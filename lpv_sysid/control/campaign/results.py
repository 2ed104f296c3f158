"""Per-run results of the campaign (:class:`RunResult`: settle time, tracking RMS per axis,
achieved equilibrium) and the trim-table rows built from them (:func:`trim_rows`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np


@dataclass
class RunResult:
    """Per-run numbers for the summary (and the trim table)."""

    name: str
    vertex: tuple
    kind: str
    complete: bool = False
    reason: str = ""
    t_command: float = math.nan  # vertex first commanded
    settle_time: float = math.nan  # s from the vertex command to the settled dwell start
    t_start: float = math.nan  # recorded run (trim) start
    t_excite: float = math.nan  # excitation start
    t_end: float = math.nan
    height_start: float = math.nan
    height_min: float = math.inf
    height_max: float = -math.inf
    distance_max: float = 0.0
    tracking_rms: dict = field(default_factory=dict)  # u, v, w [m/s], r [rad/s] (trim+excitation)
    achieved: dict = field(default_factory=dict)  # Table 1 columns (FRD) over the trim average
    achieved_frame: tuple = ()  # mean velocity in the command frame
    hold_correction: float = 0.0  # frozen trim correction (NED z) [m/s]
    _sq: np.ndarray = field(default_factory=lambda: np.zeros(4))
    _n: int = 0
    _trim_v: list = field(default_factory=list)
    _trim_vf: list = field(default_factory=list)
    _trim_e: list = field(default_factory=list)
    _trim_rotor: list = field(default_factory=list)

    def to_dict(self) -> dict:
        def r(x, n=4):
            return (
                None
                if x is None or (isinstance(x, float) and not math.isfinite(x))
                else round(float(x), n)
            )

        return {
            "name": self.name,
            "vertex": list(self.vertex),
            "kind": self.kind,
            "complete": self.complete,
            "reason": self.reason,
            "settle_time_s": r(self.settle_time),
            "t_command": r(self.t_command, 3),
            "t_start": r(self.t_start, 3),
            "t_excite": r(self.t_excite, 3),
            "t_end": r(self.t_end, 3),
            "height_start_m": r(self.height_start, 2),
            "height_min_m": r(self.height_min, 2),
            "height_max_m": r(self.height_max, 2),
            "distance_max_m": r(self.distance_max, 2),
            "tracking_rms": {k: r(v) for k, v in self.tracking_rms.items()},
            "achieved_frame": [r(v) for v in self.achieved_frame],
            "achieved": {k: r(v) for k, v in self.achieved.items()},
            "hold_correction_m_s": r(self.hold_correction),
        }


def trim_rows(results: Sequence[RunResult]) -> list[dict]:
    """Rows for :func:`lpv_sysid.sim.phase1.write_trim_table` (achieved equilibria of the
    complete runs; seed 0 Table 1 values where the vertex is one of the seed's)."""
    from lpv_sysid.models.quadrotor import SEED0_TABLE1, TRIM_COLUMNS

    rows = []
    for res in results:
        if not res.complete or not res.achieved:
            continue
        ach = {k: float(res.achieved.get(k, math.nan)) for k in TRIM_COLUMNS}
        row = {"run": res.name, "vertex": [float(c) for c in res.vertex], "achieved": ach}
        u, v, w = (int(round(c)) for c in res.vertex)  # a vertex is (u, v, w)
        key = (u, v, w)
        if key in SEED0_TABLE1 and np.allclose(res.vertex, key):
            row["seed0_table1"] = dict(zip(TRIM_COLUMNS, SEED0_TABLE1[key]))
        rows.append(row)
    return rows
