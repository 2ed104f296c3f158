"""The verifier's own reader of the identified element intervals (seed 0 Eq. 22).

Read from the raw ``vertex_models.yaml`` mapping, not through the synthesis code, so the
``box claim`` check (:mod:`lpv_sysid.synthesis.verify.box`) and the full-box Monte Carlo
(:mod:`lpv_sysid.synthesis.verify.montecarlo`) compare the certificate with the file itself.
Rule: the stored ``[lower, upper]`` where ``lower < upper``; ``nominal +/- k std`` where the file
stores ``lower = upper`` with ``std > 0`` (and for every element with ``kept="ksigma"``); fixed at
``nominal`` otherwise. ``k`` = ``meta.k_sigma`` of the models file (raised to the Sidak value when
``meta.joint_alpha`` is set, as ``ident.uncertainty.build`` does), else 3.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from lpv_sysid.errors import ConfigError

# --------------------------------------------------------------------------- full identified box
#: half-width multiplier of Eq. (22) when the models file records none (ident default k_sigma)
DEFAULT_K_SIGMA = 3.0


@dataclass(frozen=True)
class ElementBox:
    """Full identified intervals of one scheduling vertex (seed 0 Eq. 22): element l is
    ``A[row, col]`` (is_a) or ``B[row, col]`` in ``[lower_l, upper_l]``."""

    is_a: np.ndarray  # (p,) bool
    row: np.ndarray  # (p,) int
    col: np.ndarray  # (p,) int
    nominal: np.ndarray  # (p,)
    lower: np.ndarray  # (p,)
    upper: np.ndarray  # (p,)
    source: tuple  # (p,) "stored" | "k*std" | "fixed"

    def apply(
        self, A: np.ndarray, B: np.ndarray, theta: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        A, B = A.copy(), B.copy()
        A[self.row[self.is_a], self.col[self.is_a]] = theta[self.is_a]
        B[self.row[~self.is_a], self.col[~self.is_a]] = theta[~self.is_a]
        return A, B


def _meta(raw: dict) -> dict:
    meta = raw.get("meta")
    return meta if isinstance(meta, dict) else {}


def full_box_k(raw: dict, k_sigma: Optional[float] = None) -> tuple[float, str]:
    """k of Eq. (22): the argument, else ``meta.k_sigma`` of the models file, else 3.
    Returns (k, where)."""
    if k_sigma is not None:
        k, where = float(k_sigma), "given"
    else:
        meta = _meta(raw)
        k, where = (
            (float(meta["k_sigma"]), "models meta.k_sigma")
            if meta.get("k_sigma") is not None
            else (DEFAULT_K_SIGMA, "default (models file records no k_sigma)")
        )
    if not (np.isfinite(k) and k > 0):
        raise ConfigError(f"full-box check: k_sigma must be > 0, got {k!r}")
    return k, where


def full_box_intervals(
    raw: dict, k_sigma: Optional[float] = None, kept: str = "stored"
) -> tuple[list, float, str]:
    """One :class:`ElementBox` per vertex (box order) from the raw ``vertex_models.yaml`` mapping.

    Rule (module docstring): stored ``[lower, upper]`` where ``lower < upper`` (``kept ==
    "stored"``), ``nominal +/- k std`` where ``lower == upper`` and ``std > 0`` (and for every
    element with ``kept == "ksigma"``), fixed at ``nominal`` when ``std == 0`` and
    ``lower == upper``.
    With ``meta.joint_alpha`` k is raised to the Sidak value per vertex (ident.uncertainty.build).
    """
    if kept not in ("stored", "ksigma"):
        raise ConfigError(f"full-box check: kept must be 'stored' or 'ksigma', got {kept!r}")
    k0, where = full_box_k(raw, k_sigma)
    meta = _meta(raw)
    alpha = meta.get("joint_alpha") if k_sigma is None else None
    out = []
    for i, v in enumerate(raw.get("vertices") or []):
        els = v.get("uncertain") or []
        k = k0
        if alpha is not None and els:
            from lpv_sysid.ident.vertex import sidak_k

            k = max(k0, sidak_k(len(els), float(alpha)))
        cols: dict[str, list] = {
            key: [] for key in ("is_a", "row", "col", "nominal", "lower", "upper", "source")
        }
        for e in els:
            try:
                nom, std = float(e["nominal"]), float(e.get("std", 0.0))
                lo, hi = float(e["lower"]), float(e["upper"])
                isa, r, c = e["matrix"] == "A", int(e["row"]), int(e["col"])
            except (KeyError, TypeError, ValueError) as exc:
                raise ConfigError(
                    f"models: vertices[{i}].uncertain: bad entry {e!r} ({exc})"
                ) from None
            if not all(np.isfinite([nom, std, lo, hi])) or std < 0:
                raise ConfigError(
                    f"models: vertices[{i}].uncertain {e.get('matrix')}[{r},{c}]: "
                    "non-finite bounds or negative std"
                )
            if hi > lo and kept == "stored":
                src = "stored"
            elif std > 0:
                lo, hi, src = nom - k * std, nom + k * std, "k*std"
            else:
                src = "fixed" if hi == lo else "stored"
            for key, val in zip(cols, (isa, r, c, nom, lo, hi, src)):
                cols[key].append(val)
        out.append(
            ElementBox(
                np.array(cols["is_a"], dtype=bool),
                np.array(cols["row"], dtype=int),
                np.array(cols["col"], dtype=int),
                np.array(cols["nominal"], dtype=float),
                np.array(cols["lower"], dtype=float),
                np.array(cols["upper"], dtype=float),
                tuple(cols["source"]),
            )
        )
    return out, k0, where
