"""The ``vertex_models.yaml`` document of the identified vertices (format ``@2``,
:mod:`lpv_sysid.io.formats`): the vertices in box order (``models.lpv.box_vertices``) and
``meta``, how the file was made."""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident.vertex import uncertainty as unc
from lpv_sysid.ident.vertex.config import IdentificationConfig
from lpv_sysid.ident.vertex.types import VertexResult
from lpv_sysid.models.quadrotor import (
    INPUT_NAMES,
    INPUT_UNITS,
    SCHEDULING_NAMES,
    STATE_NAMES,
    STATE_UNITS,
)


def vertex_order(results: Sequence[VertexResult], cfg: IdentificationConfig) -> list[int]:
    """Index into ``results`` for every box vertex in the order of ``models.lpv.box_vertices``."""
    from lpv_sysid.models.lpv import box_vertices

    corners = box_vertices(cfg.vmin, cfg.vmax)
    order = []
    for c in corners:
        hits = [k for k, r in enumerate(results) if np.allclose(r.scheduling, c)]
        if len(hits) != 1:
            raise ConfigError(
                f"need exactly one identified maneuver at vertex {c.tolist()}, found {len(hits)}"
            )
        order.append(hits[0])
    return order


def vertex_models_dict(
    results: Sequence[VertexResult], cfg: IdentificationConfig, validation: dict | None = None
) -> dict:
    """The ``vertex_models.yaml`` document (format ``@2``, io/formats/vertex_models.py), vertices
    in box order.

    ``meta`` records how the file was made: the method, ``k_sigma`` of Eq. (22) (and the
    ``k`` applied per vertex when ``joint_alpha`` raises it), how the standard errors were
    estimated (covariance method, Student-t degrees of freedom and the resulting widening of
    the stored ``std``), how the motor constants entered, the operating point (the flown trim
    mean, the identified model's derivative there and the equilibrium it was re-expanded
    about), the reduction of Eq. (23) the identification would apply (``M_i``, absorption
    factor; the file itself stores the whole box), and the independent validation (Table 3).
    """
    from lpv_sysid.ident.equation_error import t_factor
    from lpv_sysid.io.formats import MODELS_FORMAT

    order = vertex_order(results, cfg)
    ks = [unc.applied_k(cfg.uncertainty, len(results[k].uncertain.intervals)) for k in order]
    dofs = [results[k].fit.dof for k in order]

    def vec(a):
        return None if a is None else [float(v) for v in a]

    meta = {
        "generator": "lpv_sysid.ident (seed 0 Sec. IV, Appendix B)",
        "model": cfg.model,
        "derivatives": dataclasses.asdict(cfg.derivatives),
        "k_sigma": cfg.uncertainty.k_sigma,
        "joint_alpha": cfg.uncertainty.joint_alpha,
        "intervals": "every identified element, lower/upper = nominal -/+ k std (Eq. 22)",
        "std": {
            "method": results[order[0]].fit.cov_method,
            "meaning": "standard error widened so that nominal +/- k std keeps the normal "
            "coverage 2 Phi(k) - 1 under Student-t(dof) errors",
            "dof": [None if d is None else float(d) for d in dofs],
            "t_factor": [t_factor(k, d) for k, d in zip(ks, dofs)],
        },
        "motor": [dict(results[k].motor) for k in order],
        "operating_point": {
            "x0": (
                "equilibrium of the identified model at the commanded vertex velocity v_d "
                "(re-expanded from the flown point, expand_at: commanded)"
                if cfg.expand_at == "commanded"
                else "equilibrium of the identified model at the flown velocity"
            )
            if cfg.model == "taylor2" and cfg.equilibrium
            else "mean over the trim window (flown)",
            "x_flown": [vec(results[k].x_flown) for k in order],
            "u_flown": [vec(results[k].u_flown) for k in order],
            "xdot_flown": [vec(results[k].xdot_flown) for k in order],
        },
        "uncertainty": {
            "method": cfg.uncertainty.method,
            "p_max": cfg.uncertainty.p_max,
            "k_applied": ks,
            "M": [results[k].uncertain.M for k in order],
            "inflation": [results[k].uncertain.inflation for k in order],
        },
    }
    if cfg.interpolation_pad:
        from lpv_sysid.ident.vertex.interpolation import interpolation_pad
        from lpv_sysid.ident.vertex.uncertainty import DEFAULT_JOINT_PROBABILITY

        pad = interpolation_pad([results[k] for k in order], DEFAULT_JOINT_PROBABILITY)
        if pad is not None:
            meta["interpolation"] = pad
    if validation:
        val_meta: dict[str, Any] = {
            "maneuver": validation.get("name", ""),
            "tic": {k: float(v) for k, v in validation["tic"].items()},
            "nrmse": {k: float(v) for k, v in validation["nrmse"].items()},
        }
        meta["validation"] = val_meta
        oe = validation.get("output_error")
        if oe:  # free run restarted every horizon_s (ident/vertex/pipeline.free_run)
            val_meta["output_error"] = {
                "horizon_s": float(oe["horizon_s"]),
                "tic": {k: float(v) for k, v in oe["tic"].items()},
                "nrmse": {k: float(v) for k, v in oe["nrmse"].items()},
            }
    return {
        "format": MODELS_FORMAT,
        "time": "continuous",
        "states": [{"name": n, "unit": s} for n, s in zip(STATE_NAMES, STATE_UNITS)],
        "inputs": [{"name": n, "unit": s} for n, s in zip(INPUT_NAMES, INPUT_UNITS)],
        "scheduling": {
            "names": list(SCHEDULING_NAMES),
            "min": list(cfg.vmin),
            "max": list(cfg.vmax),
        },
        "vertices": [results[k].to_dict() for k in order],
        "meta": meta,
    }


def box_corners(cfg: IdentificationConfig) -> np.ndarray:
    """The 2^3 scheduling vertices in box order (``models.lpv.box_vertices``)."""
    from lpv_sysid.models.lpv import box_vertices

    return box_vertices(cfg.vmin, cfg.vmax)
