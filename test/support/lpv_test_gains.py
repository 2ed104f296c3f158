"""A valid, stabilising, flyable ``gains.yaml`` for node / replay tests and benchmarks.

Per vertex of the box [-b, b]^3 (m/s): trim and analytic linearisation of the seed 0
quadrotor (models/quadrotor/model.py), continuous LQR gain ``K = -R^-1 B^T P`` (scipy CARE).
This is a simple stabilising LPV law -- *not* the Lemma 1 synthesis -- so the certificate
block records what it is ("LQR test gains"). What the flight runtime requires of every
gains file, this writer provides honestly for its own law:

* ``certificate.sidecar``: ``<stem>.cert.npz`` holding the systems the law was designed on
  (one per vertex: the trim linearisation), so the runtime's closed-loop re-check
  (eig(A_i + B_i K_i)) runs on them;
* ``certificate.design``: the signal the law is meant for (reference band <= 0.2 Hz as in
  config/signals_phase2.yaml, peak 0.9 b, fades >= 1 s, normalised |u_e| <= 1);
* ``certificate.gains_sha256``: the hash of the law it wrote (io.formats.certify_law).

``write_gains(path, edit=...)`` applies ``edit`` to the document before certifying: a test
that flies a deliberately different law (e.g. K x 1.25) certifies that law, and the
stability re-check still judges it on the true systems. To test tampering, edit the written
file afterwards.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
from scipy.linalg import solve_continuous_are

from lpv_sysid.io.files import sha256_file
from lpv_sysid.io.formats import GainSchedule, certify_law, systems_arrays
from lpv_sysid.models.lpv import box_vertices
from lpv_sysid.models.quadrotor import (
    INPUT_NAMES,
    INPUT_UNITS,
    STATE_NAMES,
    STATE_UNITS,
    Quadrotor,
)
from lpv_sysid.signals.excitation import envelope_dict

QW = np.diag([1, 1, 20, 20, 20, 0.1, 0.1, 0.1, 1e-6, 1e-4, 1e-4, 1e-6])
RW = np.diag([10.0, 100.0, 100.0, 10.0])


def _vertices(box: float) -> list:
    """Per vertex (scheduling, trim, A, B, K)."""
    quad = Quadrotor()
    out = []
    for v in box_vertices([-box] * 3, [box] * 3):
        tr = quad.trim(v)
        a, b = quad.linearize(tr)
        P = solve_continuous_are(a, b, QW, RW)
        out.append((v, tr, a, b, -np.linalg.solve(RW, b.T @ P)))
    return out


def design_for(box: float) -> dict:
    """``certificate.design`` of the test law (module docstring)."""
    return envelope_dict(
        [0.9 * box] * 3,
        [0.2] * 3,
        0.02,
        [1.0] * 4,
        fade_s=1.0,
        source="LQR test law: phase-2 reference band <= 0.2 Hz "
        "(config/signals_phase2.yaml), fades >= 1 s, |u_e| <= 1",
    )


def gains_dict(box: float = 2.0, design: dict | None = None) -> dict:
    """The document without sidecar and hash (what :func:`write_gains` completes)."""
    vertices = [
        {
            "scheduling": [float(c) for c in v],
            "K": K.tolist(),
            "x0": tr.x0.tolist(),
            "u0": tr.u0.tolist(),
        }
        for v, tr, _, _, K in _vertices(box)
    ]
    return {
        "format": "lpv_sysid/gains@1",
        "states": [{"name": n, "unit": u} for n, u in zip(STATE_NAMES, STATE_UNITS)],
        "inputs": [{"name": n, "unit": u} for n, u in zip(INPUT_NAMES, INPUT_UNITS)],
        "scheduling": {"names": ["u_d", "v_d", "w_d"], "min": [-box] * 3, "max": [box] * 3},
        "vertices": vertices,
        "R": (0.02 * np.eye(4)).tolist(),
        "Q": (5.0 * np.eye(3)).tolist(),
        "gamma": 10.0,
        "certificate": {
            "lmi": "none: LQR test gains (not seed 0 Lemma 1)",
            "solver": "scipy CARE",
            "gamma_achieved": 10.0,
            "min_margin": 0.0,
            "models_sha256": hashlib.sha256(b"quadrotor defaults").hexdigest(),
            "design": design if design is not None else design_for(box),
        },
    }


def write_gains(path, box: float = 2.0, edit=None, design: dict | None = None) -> str:
    """Write ``path`` and its sidecar ``<stem>.cert.npz`` (module docstring); ``edit(doc)``
    changes the document before it is certified."""
    path = Path(path)
    d = gains_dict(box, design)
    if edit is not None:
        edit(d)
    side = path.with_name(path.stem + ".cert.npz")
    systems = [[(a, b)] for _, _, a, b, _ in _vertices(box)]
    with open(side, "wb") as fh:
        np.savez(fh, **systems_arrays(systems))
    d["certificate"]["sidecar"] = {"file": side.name, "sha256": sha256_file(side)}
    GainSchedule.from_dict(certify_law(d)).save(str(path))
    return str(path)
