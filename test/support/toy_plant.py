"""The two-state, two-vertex toy plant x' = -x + u (scheduling s in [-1, 1]) with K = -I,
written as a vertex_models.yaml / gains.yaml pair: the frozen closed loop is -2 I, whose
H-inf norm from u_e to x2 is 0.5. Tests choose the identified element intervals and the
numbers the hand-made certificate claims."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import yaml

from lpv_sysid.io.files import sha256_file
from lpv_sysid.io.formats import certify_law

NAMES = [{"name": "x1", "unit": "m/s"}, {"name": "x2", "unit": "m/s"}]
INPUTS = [{"name": "u1", "unit": "1"}, {"name": "u2", "unit": "1"}]
SCHEDULING = {"names": ["s"], "min": [-1.0], "max": [1.0]}
CORNERS = (-1.0, 1.0)


def write_toy_plant(
    tmp: Path,
    uncertain: Sequence[list],
    k_sigma: float,
    gamma_achieved: float,
    min_margin: float,
) -> tuple[Path, Path]:
    """Write ``tmp/vertex_models.yaml`` (``uncertain[i]``: the element list of vertex i) and
    ``tmp/gains.yaml`` (certificate claiming ``gamma_achieved`` / ``min_margin``); return
    ``(gains, models)``."""
    verts = [
        {
            "scheduling": [s],
            "x0": [0.0, 0.0],
            "u0": [0.0, 0.0],
            "A": [[-1.0, 0.0], [0.0, -1.0]],
            "B": [[1.0, 0.0], [0.0, 1.0]],
            "uncertain": list(u),
        }
        for s, u in zip(CORNERS, uncertain)
    ]
    models = tmp / "vertex_models.yaml"
    models.write_text(
        yaml.safe_dump(
            {
                "format": "lpv_sysid/vertex_models@1",
                "time": "continuous",
                "states": NAMES,
                "inputs": INPUTS,
                "scheduling": SCHEDULING,
                "vertices": verts,
                "meta": {"k_sigma": k_sigma},
            },
            sort_keys=False,
        )
    )
    cert = {
        "lmi": "hand-made for the test",
        "solver": "none",
        "gamma_achieved": gamma_achieved,
        "min_margin": min_margin,
        "models_sha256": sha256_file(models),
        "uncertainty": {},
        "velocity_states": ["x2"],
        # K x(t - tau) on x' = -x + u: K A_cl (sI - A_cl)^-1 B + K B = -s / (s + 2), norm 1, so
        # stable for every delay below 1 s (small gain); 0.1 s is re-proven by the verifier
        "loop_delay": {"bound_s": 0.1, "stability_margin_s": 1.0, "performance_margin_s": 0.7},
    }
    gverts = [
        {"scheduling": [s], "K": [[-1.0, 0.0], [0.0, -1.0]], "x0": [0.0, 0.0], "u0": [0.0, 0.0]}
        for s in CORNERS
    ]
    gains = tmp / "gains.yaml"
    gains.write_text(
        yaml.safe_dump(
            certify_law(
                {
                    "format": "lpv_sysid/gains@1",
                    "states": NAMES,
                    "inputs": INPUTS,
                    "scheduling": SCHEDULING,
                    "vertices": gverts,
                    "R": [[1.0, 0.0], [0.0, 1.0]],
                    "Q": [[1.0]],
                    "gamma": 1.0,
                    "certificate": cert,
                },
                layout=None,
            ),  # the law hash and the seal, as the certifying tool writes them
            sort_keys=False,
        )
    )
    return gains, models
