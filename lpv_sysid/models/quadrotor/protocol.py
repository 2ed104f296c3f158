"""What the trim solver and the linearisation read of a quadrotor model.

:mod:`~lpv_sysid.models.quadrotor.trim` and :mod:`~lpv_sysid.models.quadrotor.linear` are
functions of the model that :class:`~lpv_sysid.models.quadrotor.model.Quadrotor` exposes as
methods; they name the model by this protocol, so the parts do not import the model class.
"""

from __future__ import annotations

from typing import Callable, Protocol

import numpy as np

from lpv_sysid.models.quadrotor.params import QuadrotorParams


class QuadrotorModel(Protocol):
    """Parameters, mixer (seed 0 Eq. 7), inertia and the Eq. (3) right-hand side."""

    params: QuadrotorParams
    mix: np.ndarray
    mix_inv: np.ndarray
    inertia: np.ndarray
    inertia_inv: np.ndarray
    #: the 16-state derivative on plain sequences (the generated hot path)
    derivatives_list: Callable[[list, list], list]

    def derivatives(self, x16, u) -> np.ndarray:
        """Time derivative of the full 16-state model (seed 0 Eqs. 3, 6, 7, 8)."""
        ...
