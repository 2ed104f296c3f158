"""Cascaded MIMO VRFT (seed 1 Sec. 3.3.4, Eqs. 3.32-3.34 and the pseudo-code steps 1-11).

Inner loop first: ``theta_i`` from ``{u, y_i}`` with ``M_i`` (steps 1-5). The inner reference that
the tuned inner controller would have needed is rebuilt, ``r_i = C_i^-1(theta_i) u + y_i``
(Eqs. 3.32-3.33, step 6, which requires ``C_i`` minimum phase), and it becomes the input of the
outer problem ``{r_i, y_o}`` with ``M_o`` (Eq. 3.34, steps 7-11).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lpv_sysid.vrft.controller import VrftResult, invert_controller
from lpv_sysid.vrft.controller_class import ControllerClass
from lpv_sysid.vrft.tf import Tf, TfMatrix
from lpv_sysid.vrft.tuning import vrft


@dataclass
class CascadeResult:
    inner: VrftResult
    outer: VrftResult
    r_inner: np.ndarray  # virtual inner reference r_i (N, n_yi), Eq. (3.32)


def cascaded_vrft(
    u,
    y_inner,
    y_outer,
    M_inner: TfMatrix,
    M_outer: TfMatrix,
    cls_inner: ControllerClass,
    cls_outer: ControllerClass,
    *,
    method: str = "ls",
    window: int = 5,
    prefilter_inner: Tf | None = None,
    prefilter_outer: Tf | None = None,
    discard: int = 0,
    eiv_weight: str = "identity",
) -> CascadeResult:
    """Seed 1 Sec. 3.3.4 pseudo-code. ``method`` ('ls' or 'eiv') is used for both loops.

    Raises SolverError (from :func:`invert_controller`) when the inner controller is not minimum
    phase: the pseudo-code then asks to return to step 1 with another reference model.
    """
    inner = vrft(
        u,
        y_inner,
        M_inner,
        cls_inner,
        method=method,
        window=window,
        prefilter=prefilter_inner,
        discard=discard,
        eiv_weight=eiv_weight,
    )  # steps 1-5
    y_i = np.asarray(y_inner, dtype=float).reshape(len(y_inner), -1)
    r_i = invert_controller(inner, u) + y_i  # step 6
    outer = vrft(
        r_i,
        y_outer,
        M_outer,
        cls_outer,
        method=method,
        window=window,
        prefilter=prefilter_outer,
        discard=discard,
        eiv_weight=eiv_weight,
    )  # steps 7-11
    return CascadeResult(inner, outer, r_i)
