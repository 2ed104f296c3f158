"""The identified vertex models for the tools engineers already use (issue 23 item 4): a
MATLAB ``.mat`` file (:func:`save_models_mat`, scipy.io, MATLAB 5 format: MATLAB, Octave,
SIDPAC/CIFER scripts read it) and python-control state-space objects
(:func:`control_systems`). Both carry exactly what ``vertex_models.yaml`` holds
(:class:`~lpv_sysid.io.formats.VertexModels`); the YAML file stays the one the package reads.

``.mat`` variables (``nx`` states, ``nu`` inputs, ``nv`` vertices, ``np`` scheduling axes):

====================  ============  ===============================================================
variable              size          content
====================  ============  ===============================================================
``A``, ``B``          nx x nx x nv  nominal ``dx_dot = A dx + B du`` per vertex (seed 0 Eq. 20)
                      nx x nu x nv
``x0``, ``u0``        nx x nv       equilibrium state and input per vertex (seed 0 Table 1)
``scheduling``        np x nv       the vertex's scheduling point (box order)
``box_min, box_max``  np x 1        the scheduling box
``Ts``                1 x 1         0 for continuous time, else the sample time [s]
``state_names``, ...  cell          ``state_names``, ``state_units``, ``input_names``,
                                    ``input_units``, ``scheduling_names``
``uncertain``         k x 8         rows ``[vertex, matrix (1 = A, 2 = B), row, col, nominal,
                                    std, lower, upper]``, MATLAB 1-based indices (seed 0 Eq. 22)
``format``            string        ``lpv_sysid/vertex_models.mat@1``
====================  ============  ===============================================================
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lpv_sysid.errors import ConfigError

if TYPE_CHECKING:
    from lpv_sysid.io.formats.vertex_models import VertexModels

MAT_FORMAT = "lpv_sysid/vertex_models.mat@1"
UNCERTAIN_COLUMNS = ("vertex", "matrix", "row", "col", "nominal", "std", "lower", "upper")


def _cell(names) -> np.ndarray:
    out = np.empty((len(names), 1), dtype=object)
    for i, n in enumerate(names):
        out[i, 0] = str(n)
    return out


def models_mat_dict(models: VertexModels) -> dict[str, Any]:
    """The ``.mat`` variables of ``models`` (module docstring)."""
    vs = models.vertices
    unc = [
        [
            k + 1,
            1 if e.matrix == "A" else 2,
            e.row + 1,
            e.col + 1,
            e.nominal,
            e.std,
            e.lower,
            e.upper,
        ]
        for k, v in enumerate(vs)
        for e in v.uncertain
    ]
    return {
        "format": MAT_FORMAT,
        "A": np.stack([v.A for v in vs], axis=2),
        "B": np.stack([v.B for v in vs], axis=2),
        "x0": np.column_stack([v.x0 for v in vs]),
        "u0": np.column_stack([v.u0 for v in vs]),
        "scheduling": np.column_stack([v.scheduling for v in vs]),
        "box_min": np.asarray(models.scheduling.min, float).reshape(-1, 1),
        "box_max": np.asarray(models.scheduling.max, float).reshape(-1, 1),
        "Ts": 0.0 if models.ts is None else float(models.ts),
        "state_names": _cell(models.state_names),
        "state_units": _cell(models.state_units),
        "input_names": _cell(models.input_names),
        "input_units": _cell(models.input_units),
        "scheduling_names": _cell(models.scheduling.names),
        "uncertain": np.array(unc, dtype=float).reshape(-1, len(UNCERTAIN_COLUMNS)),
        "uncertain_columns": _cell(UNCERTAIN_COLUMNS),
    }


def save_models_mat(models: VertexModels, path: str | Path) -> Path:
    """Write ``models`` as a MATLAB 5 ``.mat`` file (module docstring)."""
    from scipy.io import savemat

    p = Path(path)
    try:
        savemat(str(p), models_mat_dict(models), do_compression=True, oned_as="column")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot write ({exc.strerror or exc})") from None
    return p


def control_systems(models: VertexModels) -> list:
    """One python-control ``StateSpace`` per vertex (box order), named channels, ``dt`` 0 for
    continuous time; ConfigError when python-control is not installed (requirements.txt)."""
    try:
        import control
    except ImportError:
        raise ConfigError("python-control is not installed (requirements.txt pins it)") from None
    n_x = len(models.state_names)
    out = []
    for k, v in enumerate(models.vertices):
        sched = ",".join(f"{x:g}" for x in v.scheduling)
        out.append(
            control.ss(
                v.A,
                v.B,
                np.eye(n_x),
                np.zeros((n_x, len(models.input_names))),
                0 if models.ts is None else models.ts,
                name=f"vertex_{k}[{sched}]",
                inputs=list(models.input_names),
                outputs=list(models.state_names),
                states=list(models.state_names),
            )
        )
    return out
