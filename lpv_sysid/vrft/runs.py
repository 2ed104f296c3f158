"""A VRFT run on data (seed 1 Sec. 3.3): the data file, the tuning (single loop or the
cascade of Sec. 3.3.4) and the controller document (``lpv-sysid vrft``).

The data file ``FILE.npz`` holds ``t`` (N,), ``u`` (N, n_u), ``y`` (N, n_y); optionally ``y2``
(second experiment, method iv), ``instrument`` (N, q: external excitation for EIV on
closed-loop data) and, with an ``outer`` config section, ``y_outer`` (cascade).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.vrft.cascade import cascaded_vrft
from lpv_sysid.vrft.config import VrftConfig
from lpv_sysid.vrft.tuning import vrft

#: format of the controller document :func:`tune` returns
FORMAT = "lpv_sysid/vrft_controller@1"

#: the VRFT settings of the thesis benchmarks (seed 1 Table 5.3, LV100 Tables 5.1-5.2)
TABLE53_CONFIG = {
    "reference_model": {"poles": [0.9, 0.9]},
    "controller": {"basis": "pid", "terms": ["p", "i"], "structure": "full"},
    "method": "ls",
    "window": 10,
    "Ts": 1.0,
}
LV100_CONFIG = {
    "reference_model": {"poles": [0.6, 0.6]},
    "controller": {"basis": "pid", "terms": ["p", "i"], "structure": "full"},
    "method": "eiv",
    "window": 20,
    "Ts": 0.1,
}


@dataclass
class TuneResult:
    """The controller document (``format``: :data:`FORMAT`), the result object per loop
    (``controller``, or ``inner`` and ``outer``) for reporting."""

    doc: dict[str, Any]
    loops: dict[str, Any] = field(default_factory=dict)


def load_data(path: str) -> dict:
    """The arrays of a VRFT data file, checked: numeric, finite, one sample per ``t``, ``t``
    strictly increasing and uniformly sampled (VRFT needs a fixed sample time)."""
    from lpv_sysid.io.files import read_npz

    p = Path(path)
    if not os.path.lexists(p):
        raise ConfigError(f"data file not found: {p}")
    d = read_npz(p)  # regular file, size cap, no pickles, no complex arrays
    for k in ("t", "u", "y"):
        if k not in d:
            raise ConfigError(f"{p}: missing array {k!r} (have {sorted(d)})")
    for k, v in d.items():
        if v.dtype.kind not in "fiu":
            raise ConfigError(f"{p}: array {k!r} is not numeric (dtype {v.dtype})")
        if not np.all(np.isfinite(v)):
            raise ConfigError(f"{p}: array {k!r} contains NaN/inf")
    t = d["t"].reshape(-1)
    for k in d:
        if k != "t" and d[k].shape[0] != t.size:
            raise ConfigError(f"{p}: {k!r} has {d[k].shape[0]} samples but t has {t.size}")
    if t.size < 2 or np.any(np.diff(t) <= 0):
        raise ConfigError(f"{p}: t must be strictly increasing with at least 2 samples")
    dt = np.diff(t)
    if np.max(np.abs(dt - dt.mean())) > 1e-6 * max(dt.mean(), 1e-12) + 1e-9:
        raise ConfigError(f"{p}: t is not uniformly sampled (VRFT needs a fixed sample time)")
    d["t"] = t
    return d


def tune(cfg: VrftConfig, data: dict, source: str) -> TuneResult:
    """VRFT of ``cfg`` on ``data`` (:func:`load_data`; ``source`` names it in the document)."""
    t = data["t"]
    Ts = cfg.Ts if cfg.Ts is not None else float(np.mean(np.diff(t)))
    u = data["u"].reshape(t.size, -1).astype(float)
    y = data["y"].reshape(t.size, -1).astype(float)
    cls = cfg.loop.controller_class(u.shape[1], Ts)
    W = cfg.loop.prefilter_tf()
    doc = {
        "format": FORMAT,
        "Ts": Ts,
        "method": cfg.method,
        "window": cfg.window,
        "eiv_weight": cfg.eiv_weight,
        "source": source,
    }
    if cfg.outer is not None:
        if cfg.method == "iv":
            raise ConfigError("cascade (outer:) supports method ls or eiv, not iv")
        if "y_outer" not in data:
            raise ConfigError(
                "config has an 'outer' loop but the data file has no 'y_outer' array"
            )
        yo = data["y_outer"].reshape(t.size, -1).astype(float)
        cls_o = cfg.outer.controller_class(y.shape[1], Ts)
        cascade = cascaded_vrft(
            u,
            y,
            yo,
            cfg.loop.M,
            cfg.outer.M,
            cls,
            cls_o,
            method=cfg.method,
            window=cfg.window,
            prefilter_inner=W,
            prefilter_outer=cfg.outer.prefilter_tf("outer.prefilter"),
            discard=cfg.discard,
            eiv_weight=cfg.eiv_weight,
        )
        doc["inner"] = cascade.inner.to_dict()
        doc["outer"] = cascade.outer.to_dict()
        return TuneResult(doc, {"inner loop": cascade.inner, "outer loop": cascade.outer})
    res = vrft(
        u,
        y,
        cfg.loop.M,
        cls,
        method=cfg.method,
        prefilter=W,
        window=cfg.window,
        instrument=data.get("instrument"),
        y2=data.get("y2"),
        discard=cfg.discard,
        eiv_weight=cfg.eiv_weight,
    )
    doc["controller"] = res.to_dict()
    return TuneResult(doc, {"controller": res})
