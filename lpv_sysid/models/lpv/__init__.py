"""Polytopic (uncertain) LPV model over the scheduling box of seed 0 Eqs. (20)-(23).

Parts: the model object (:class:`PolytopicModel`, :class:`ScheduledLpv`,
:mod:`~lpv_sysid.models.lpv.polytope`) and

- :mod:`~lpv_sysid.models.lpv.box`: vertex order of the box (Eq. 20) and the multilinear
  weights alpha_i(v_d) (Eq. 21), clamped outside the box;
- :mod:`~lpv_sysid.models.lpv.uncertainty`: interval elements (Eq. 22), corner enumeration of
  the nested uncertainty vertices Lambda_i^j (Eq. 23), and the common input matrix of Lemma 1
  (why B must carry no vertex index, and what that costs: that module's docstring);
- :mod:`~lpv_sysid.models.lpv.element_box`: the whole Eq. (22) box as a structured
  perturbation (LFT form) and the corner polytopes that are such boxes.
"""

from __future__ import annotations

from lpv_sysid.models.lpv.box import (
    box_vertices,
    interpolate_gain,
    multilinear_weight_gradient,
    multilinear_weights,
)
from lpv_sysid.models.lpv.element_box import ElementBox, corner_box
from lpv_sysid.models.lpv.polytope import PolytopicModel, ScheduledLpv, common_input_deviation
from lpv_sysid.models.lpv.uncertainty import (
    CommonInputSet,
    UncertainElement,
    input_corners,
    input_hull,
    product_systems,
    uncertainty_vertices,
)

__all__ = [
    "CommonInputSet",
    "ElementBox",
    "PolytopicModel",
    "ScheduledLpv",
    "UncertainElement",
    "box_vertices",
    "common_input_deviation",
    "corner_box",
    "input_corners",
    "input_hull",
    "interpolate_gain",
    "multilinear_weight_gradient",
    "multilinear_weights",
    "product_systems",
    "uncertainty_vertices",
]
