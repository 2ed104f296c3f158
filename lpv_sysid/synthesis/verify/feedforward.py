"""Independent check of the stored reference feedforward (row kinds ``feedforward``,
``ff residual``, ``ff jerk``): F_i (and F_jerk,i) recomputed from the nominal vertex models by
:mod:`lpv_sysid.synthesis.feedforward` and its defining property checked directly."""

from __future__ import annotations

from typing import Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.models.lpv import PolytopicModel
from lpv_sysid.synthesis.verify.report import VerifyReport

#: relative tolerance of the recomputed feedforward matrices (YAML keeps ~16 digits)
FF_RTOL = 1e-8


def check_feedforward(
    rep: VerifyReport,
    model: PolytopicModel,
    F_ff: np.ndarray,
    layout: dict,
    F_jerk: Optional[np.ndarray] = None,
    rtol: float = FF_RTOL,
) -> None:
    """Recompute F_i (and F_jerk,i) from the nominal vertex models (synthesis/feedforward.py) and
    compare with the stored ones; also the defining property: A_i dx_ff + B_i du_ff has the
    accelerated rows = a and the held rows = 0 for a = each unit vector (independent of how F was
    computed)."""
    from lpv_sysid.synthesis.feedforward import (
        FeedforwardLayout,
        feedforward_matrix,
        feedforward_residual,
        jerk_matrix,
    )

    try:
        lay = FeedforwardLayout.from_dict(layout)
        free, acc, held = lay.indices(model.state_names)
    except ConfigError as exc:
        rep.add("feedforward", "layout", 1.0, 0.0, False, str(exc))
        return
    F_ff = np.asarray(F_ff, dtype=float)
    want = (model.n_vertices, len(free) + model.n_u, len(acc))
    if F_ff.shape != want:
        rep.add(
            "feedforward", "F_ff shape", 1.0, 0.0, False, f"shape {F_ff.shape}, expected {want}"
        )
        return
    for i in range(model.n_vertices):
        try:
            F = feedforward_matrix(
                model.A[i], model.B[i], model.state_names, lay, where=f"vertex {i}"
            )
        except ConfigError as exc:
            rep.add("feedforward", f"vertex {i}", float("inf"), rtol, False, str(exc))
            continue
        err = float(np.max(np.abs(F_ff[i] - F)) / max(1.0, float(np.max(np.abs(F)))))
        rep.add(
            "feedforward",
            f"vertex {i} F_ff vs recomputed",
            err,
            rtol,
            err <= rtol,
            "" if err <= rtol else "stored F_ff differs from the one of the nominal model",
        )
        scale = max(1.0, float(np.max(np.abs(model.A[i]))), float(np.max(np.abs(model.B[i]))))
        res = max(
            float(
                np.max(
                    np.abs(
                        feedforward_residual(model.A[i], model.B[i], F_ff[i], free, acc, e)[
                            acc + held
                        ]
                    )
                )
            )
            for e in np.eye(len(acc))
        )
        ok = res <= 1e-9 * scale
        rep.add(
            "ff residual",
            f"vertex {i} A dx_ff + B du_ff - a",
            res,
            1e-9 * scale,
            ok,
            "" if ok else "stored F_ff does not produce the requested acceleration",
        )
        if lay.has_jerk:
            if F_jerk is None:
                rep.add(
                    "ff jerk",
                    f"vertex {i}",
                    1.0,
                    0.0,
                    False,
                    "layout declares the jerk term, F_jerk missing",
                )
                continue
            try:
                Fj = jerk_matrix(
                    model.A[i], model.B[i], model.state_names, F, lay, where=f"vertex {i}"
                )
            except ConfigError as exc:
                rep.add("ff jerk", f"vertex {i}", float("inf"), rtol, False, str(exc))
                continue
            Fj_s = np.asarray(F_jerk[i], dtype=float)
            if Fj_s.shape != Fj.shape:
                rep.add(
                    "ff jerk",
                    f"vertex {i} F_jerk shape",
                    1.0,
                    0.0,
                    False,
                    f"{Fj_s.shape} != {Fj.shape}",
                )
                continue
            err = float(np.max(np.abs(Fj_s - Fj)) / max(1.0, float(np.max(np.abs(Fj)))))
            rep.add(
                "ff jerk",
                f"vertex {i} F_jerk vs recomputed",
                err,
                rtol,
                err <= rtol,
                "" if err <= rtol else "stored F_jerk differs from the one of the nominal model",
            )
