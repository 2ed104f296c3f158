"""A valid, stabilising ``gains.yaml`` for node / replay tests and benchmarks.

Per vertex of the box [-b, b]^3 (m/s): trim and analytic linearisation of the seed 0
quadrotor (models/quadrotor.py), continuous LQR gain ``K = -R^-1 B^T P`` (scipy CARE).
This is a simple stabilising LPV law -- *not* the Lemma 1 synthesis -- so the certificate
block only records what it is ("LQR test gains"); the file passes io/formats validation.
"""

from __future__ import annotations

import hashlib

import numpy as np
from scipy.linalg import solve_continuous_are

from lpv_sysid.io.formats import GainSchedule
from lpv_sysid.models.lpv import box_vertices
from lpv_sysid.models.quadrotor import (INPUT_NAMES, INPUT_UNITS, STATE_NAMES, STATE_UNITS,
                                        Quadrotor)

QW = np.diag([1, 1, 20, 20, 20, 0.1, 0.1, 0.1, 1e-6, 1e-4, 1e-4, 1e-6])
RW = np.diag([10.0, 100.0, 100.0, 10.0])


def gains_dict(box: float = 2.0) -> dict:
    quad = Quadrotor()
    vertices = []
    for v in box_vertices([-box] * 3, [box] * 3):
        tr = quad.trim(v)
        a, b = quad.linearize(tr)
        P = solve_continuous_are(a, b, QW, RW)
        K = -np.linalg.solve(RW, b.T @ P)
        vertices.append({"scheduling": [float(c) for c in v], "K": K.tolist(),
                         "x0": tr.x0.tolist(), "u0": tr.u0.tolist()})
    return {
        "format": "lpv_sysid/gains@1",
        "states": [{"name": n, "unit": u} for n, u in zip(STATE_NAMES, STATE_UNITS)],
        "inputs": [{"name": n, "unit": u} for n, u in zip(INPUT_NAMES, INPUT_UNITS)],
        "scheduling": {"names": ["u_d", "v_d", "w_d"], "min": [-box] * 3, "max": [box] * 3},
        "vertices": vertices,
        "R": (0.02 * np.eye(4)).tolist(),
        "Q": (5.0 * np.eye(3)).tolist(),
        "gamma": 10.0,
        "certificate": {"lmi": "none: LQR test gains (not seed 0 Lemma 1)", "solver": "scipy CARE",
                        "gamma_achieved": 10.0, "min_margin": 0.0,
                        "models_sha256": hashlib.sha256(b"quadrotor defaults").hexdigest()},
    }


def write_gains(path, box: float = 2.0) -> str:
    gs = GainSchedule.from_dict(gains_dict(box))
    gs.save(str(path))
    return str(path)
