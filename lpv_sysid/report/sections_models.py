"""What a reviewer of an unstable vehicle asks first about the identified models (issue 23
item 3), from ``vertex_models.yaml`` alone:

- open-loop poles per vertex: the eigenvalues of the nominal ``A`` (seed 0 Eq. 20), the
  largest real part and the time to double ``ln 2 / max Re(lambda)`` of the divergent mode
  (amplitude ``exp(Re(lambda) t)``: it doubles in that time), or "stable";
- the identified parameters with their confidence intervals (Eq. 22: lower, upper =
  nominal -/+ k std) and significance (``|t| = |nominal| / std``; ``*``: the interval
  excludes zero), one row per element, one column per vertex.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from lpv_sysid.report.document import Report, md_table

LN2 = math.log(2.0)


def _names(models: dict, key: str) -> list[str]:
    return [str(c.get("name", i)) for i, c in enumerate(models.get(key) or [])]


def _vertex_label(v: dict) -> str:
    return "[" + " ".join(f"{float(c):+g}" for c in v.get("scheduling", [])) + "]"


def pole_rows(models: dict | None) -> list[list[Any]]:
    """Per vertex: its scheduling point, the unstable poles, max Re (1/s), time to double (s)."""
    if not isinstance(models, dict):
        return []
    rows = []
    for v in models.get("vertices") or []:
        try:
            A = np.asarray(v["A"], dtype=float)
            lam = np.linalg.eigvals(A)
        except (KeyError, TypeError, ValueError, np.linalg.LinAlgError):
            continue
        re = float(np.max(lam.real))
        unstable = sorted((x for x in lam if x.real > 1e-9), key=lambda x: -x.real)
        text = ", ".join(
            f"{x.real:+.3g}" + (f"{x.imag:+.3g}j" if abs(x.imag) > 1e-9 else "")
            for x in unstable
            if x.imag >= -1e-9
        )
        rows.append(
            [
                _vertex_label(v),
                text or "none",
                re,
                LN2 / re if re > 1e-9 else "stable",
            ]
        )
    return rows


def element_name(e: dict, states: Sequence[str], inputs: Sequence[str]) -> str:
    m, i, j = e.get("matrix"), int(e.get("row", 0)), int(e.get("col", 0))
    cols = states if m == "A" else inputs
    row = states[i] if i < len(states) else str(i)
    col = cols[j] if j < len(cols) else str(j)
    return f"{m}[{row}, {col}]"


def parameter_rows(models: dict | None) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of the identified elements: ``nominal [lower, upper] |t|``, ``*`` when
    the interval excludes zero; elements with std 0 (known, not identified) left out."""
    if not isinstance(models, dict):
        return [], []
    states, inputs = _names(models, "states"), _names(models, "inputs")
    vertices = [v for v in models.get("vertices") or [] if isinstance(v, dict)]
    table: dict[str, list[str]] = {}
    for k, v in enumerate(vertices):
        for e in v.get("uncertain") or []:
            try:
                nom, std = float(e["nominal"]), float(e["std"])
                lo, hi = float(e["lower"]), float(e["upper"])
            except (KeyError, TypeError, ValueError):
                continue
            if std <= 0.0:
                continue
            name = element_name(e, states, inputs)
            t = abs(nom) / std
            sig = "*" if lo > 0.0 or hi < 0.0 else ""
            cell = f"{nom:+.3g} [{lo:+.3g}, {hi:+.3g}] {t:.1f}{sig}"
            table.setdefault(name, [""] * len(vertices))[k] = cell
    header = ["element"] + [_vertex_label(v) for v in vertices]
    return header, [[n, *cells] for n, cells in table.items()]


def stability_section(r: Report) -> None:
    """Open-loop poles / time to double and the parameter table (module docstring)."""
    d = r.data
    r.h(2, "Identified models: open-loop stability and parameters")

    def body() -> None:
        rows = pole_rows(d.models)
        if rows:
            worst = min((x[3] for x in rows if not isinstance(x[3], str)), default=None)
            r.p(
                "Open-loop poles of each vertex's nominal A (seed 0 Eq. 20): the unstable ones "
                "(upper half plane), the largest real part and the time to double "
                "ln 2 / max Re(lambda) of the fastest divergent mode"
                + (f"; shortest: **{worst:.2f} s**." if worst is not None else ".")
            )
            r.p(
                md_table(
                    ["vertex", "unstable poles [1/s]", "max Re [1/s]", "time to double [s]"],
                    rows,
                    fmt="{:.3g}",
                )
            )
        header, prows = parameter_rows(d.models)
        if prows:
            r.p(
                "Identified parameters per vertex: nominal [lower, upper] (the Eq. 22 interval, "
                "nominal -/+ k std) and |t| = |nominal| / std; * = the interval excludes zero "
                "(significant)."
            )
            r.p(md_table(header, prows))

    r.with_input("models", "open-loop poles", body)
