"""Loading the artefacts of a run directory for the report (no plotting here).

A run directory is what ``lpv-sysid demo --out DIR`` writes (README "What the demo does").
Every input is optional; :func:`load_run` records which files were found, which are missing
and which could not be read, so the report can say so plainly.

Files looked for (first existing candidate wins):

====================  =========================================================================
phase-1 trims         ``trims.yaml``, ``phase1/trims.yaml``
vertex models         ``vertex_models.yaml`` (x0/u0 -> Table 1, fit.r2 -> Table 2)
validation            ``validation.yaml``, ``ident/validation.yaml`` (TIC/NRMSE -> Table 3)
signals               ``signals/summary.yaml`` and ``signals/signals.npz``
gains + certificate   ``gains.yaml``
verification          ``verification.yaml`` (written by ``lpv-sysid verify``, read through
                      :func:`lpv_sysid.synthesis.verify.report.read_verification`; the report
                      never re-runs the verifier: absent means "not verified")
phase 2               ``phase2/summary.yaml`` and ``phase2/*.npz`` (written by
                      :mod:`lpv_sysid.sim.phase2`)
provenance            ``phase1/experiment.yaml`` / ``phase1/campaign_summary.yaml`` (recorder and
                      campaign of ``lpv-sysid fly phase1``: flown over MAVLink) and
                      ``phase2/phase2_summary.yaml`` (``lpv-sysid fly phase2``)
flown phase 2         ``phase2/phase2_log.npz`` (its time histories) and ``phase2/experiment.yaml``
                      (its recorder: vehicle kind, site, clock)
====================  =========================================================================
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.files import read_yaml
from lpv_sysid.models.quadrotor import TRIM_TABLE
from lpv_sysid.synthesis.verify import Verification, read_verification

log = logging.getLogger(__name__)

CANDIDATES: dict[str, tuple[str, ...]] = {
    "trims": ("trims.yaml", "phase1/trims.yaml"),
    "models": ("vertex_models.yaml",),
    "validation": ("validation.yaml", "ident/validation.yaml"),
    "signals_summary": ("signals/summary.yaml", "summary.yaml"),
    "signals": ("signals/signals.npz", "signals.npz"),
    "gains": ("gains.yaml",),
    "verification": ("verification.yaml",),
    "phase2_summary": ("phase2/summary.yaml",),
    "experiment": ("phase1/experiment.yaml", "experiment.yaml"),
    "campaign": ("phase1/campaign_summary.yaml", "campaign_summary.yaml"),
    "flight_phase2": ("phase2/phase2_summary.yaml", "phase2_summary.yaml"),
    "flight_phase2_log": ("phase2/phase2_log.npz", "phase2_log.npz"),
    "flight_phase2_experiment": ("phase2/experiment.yaml",),
    "broken_loop": ("broken_loop/broken_loop_summary.yaml",),
}
#: inputs only used to say where the data came from (not listed as missing sections)
PROVENANCE_INPUTS = (
    "experiment",
    "campaign",
    "flight_phase2",
    "flight_phase2_log",
    "flight_phase2_experiment",
    "broken_loop",
)
PHASE2_SERIES = ("eq33", "nonlinear")


@dataclass
class RunData:
    """Everything the report can use; ``None`` when the input was not found or unreadable."""

    run_dir: Path
    found: dict[str, Path] = field(default_factory=dict)
    missing: dict[str, tuple[str, ...]] = field(default_factory=dict)
    problems: dict[str, str] = field(default_factory=dict)
    derived: dict[str, str] = field(default_factory=dict)  # input -> how it was obtained instead
    trims: Optional[Any] = None
    models: Optional[dict] = None
    validation: Optional[dict] = None
    signals_summary: Optional[dict] = None
    signals: Optional[dict[str, np.ndarray]] = None
    gains: Optional[dict] = None
    verification: Optional["Verification"] = None
    phase2_summary: Optional[dict] = None
    experiment: Optional[dict] = None
    campaign: Optional[dict] = None
    flight_phase2: Optional[dict] = None
    flight_phase2_log: Optional[dict[str, np.ndarray]] = None  # fly phase2's phase2_log.npz
    flight_phase2_experiment: Optional[dict] = None  # its recorder's experiment.yaml
    broken_loop: Optional[dict] = None  # the chain's broken-loop run (broken_loop_summary.yaml)
    phase2_series: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


def read_npz(path: Path) -> dict[str, np.ndarray]:
    """npz archive -> dict of arrays (:func:`lpv_sysid.io.files.opening.read_npz`: regular file,
    size cap, no pickles, no complex arrays); ConfigError naming the file otherwise."""
    from lpv_sysid.io.files import read_npz as _read_npz

    return _read_npz(path)


def _find(run_dir: Path, key: str) -> Optional[Path]:
    for rel in CANDIDATES[key]:
        p = run_dir / rel
        if os.path.lexists(
            p
        ):  # present but not a readable file (FIFO, directory, loop): a problem
            return p
    return None


def load_run(run_dir: str | Path, verify: bool = True) -> RunData:
    """Collect the artefacts of ``run_dir``. Raises ConfigError only if the directory is absent.

    ``verify`` is accepted for compatibility and has no effect: the verification is read from
    ``verification.yaml`` (``lpv-sysid verify`` writes it), never recomputed here.
    """
    del verify
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ConfigError(f"run_dir: {run_dir} is not a directory")
    data = RunData(run_dir=run_dir)
    for key in CANDIDATES:
        path = _find(run_dir, key)
        if path is None:
            data.missing[key] = CANDIDATES[key]
            continue
        data.found[key] = path
        try:
            value: Any
            if key == "verification":
                value = read_verification(path)
            elif path.suffix == ".npz":
                value = read_npz(path)
            else:
                value = read_yaml(path, finite=False)  # outputs may hold .nan
            if key not in (
                "verification",
                "signals",
                "trims",
                "flight_phase2_log",
            ) and not isinstance(value, dict):
                raise ConfigError(
                    f"{path}: expected a mapping at the top level, got {type(value).__name__}"
                )
        except ConfigError as exc:
            data.problems[key] = str(exc)
            log.warning("%s", exc)
            continue
        setattr(data, key, value)
    meta_val = (
        (data.models.get("meta") or {}).get("validation")
        if isinstance(data.models, dict)
        else None
    )
    if (
        data.validation is None
        and "validation" not in data.problems
        and isinstance(meta_val, dict)
    ):
        data.validation = meta_val
        data.derived["validation"] = "from vertex_models.yaml meta.validation"
        data.missing.pop("validation", None)
    for name in PHASE2_SERIES:
        path = run_dir / "phase2" / f"{name}.npz"
        if os.path.lexists(path):
            try:
                data.phase2_series[name] = read_npz(path)
                data.found[f"phase2_{name}"] = path
            except ConfigError as exc:
                data.problems[f"phase2_{name}"] = str(exc)
    return data


# ---------------------------------------------------------------------------------------------
# Table extraction (pure functions on the loaded objects)
# ---------------------------------------------------------------------------------------------


def _names(block: Any) -> list[str]:
    """['phi', ...] from [{name: phi, unit: rad}, ...] or ['phi', ...]."""
    if not isinstance(block, list):
        return []
    return [str(b.get("name")) if isinstance(b, dict) else str(b) for b in block]


def equilibrium_table(models: dict) -> tuple[list[str], list[list[Any]]]:
    """Seed 0 Table 1 from the vertex equilibria x0 of ``vertex_models.yaml``."""
    names = _names(models.get("states"))
    vertices = models.get("vertices") or []
    header = ["vertex [m/s]"] + [f"{n}_0 [{u}]" for n, u, _, _ in TRIM_TABLE]
    rows = []
    for k, vx in enumerate(vertices):
        x0 = vx.get("x0") if isinstance(vx, dict) else None
        sched = vx.get("scheduling") if isinstance(vx, dict) else None
        if not isinstance(x0, list) or len(x0) != len(names):
            raise ConfigError(
                f"vertex_models.yaml: vertices[{k}].x0 missing or not {len(names)} long"
            )
        row: list[Any] = [_fmt_vec(sched)]
        for n, _, scale, _ in TRIM_TABLE:
            row.append(float(x0[names.index(n)]) * scale if n in names else None)
        rows.append(row)
    return header, rows


def trims_table(trims: Any) -> tuple[list[str], list[list[Any]]]:
    """Phase-1 trims (``trims.yaml`` of :mod:`lpv_sysid.sim.phase1`, format
    ``lpv_sysid/phase1_trims@1``): per run the achieved equilibrium (mean of the trim segment,
    seed 0 Table 1), the model trim and, where the vertex matches, the seed's Table 1 row."""
    if not isinstance(trims, dict) or not isinstance(trims.get("runs"), list):
        raise ConfigError("trims.yaml: expected a mapping with a 'runs' list")
    columns = trims.get("columns") or []
    units = trims.get("units") or [""] * len(columns)
    if not columns:
        raise ConfigError("trims.yaml: 'columns' missing")
    header = ["run", "vertex [m/s]", "source"] + [
        f"{c} [{u}]" if u else str(c) for c, u in zip(columns, units)
    ]
    rows = []
    for k, run in enumerate(trims["runs"]):
        if not isinstance(run, dict):
            raise ConfigError(f"trims.yaml: runs[{k}] is not a mapping")
        for source in ("achieved", "model_trim", "seed0_table1"):
            vals = run.get(source)
            if isinstance(vals, dict):
                rows.append(
                    [run.get("run", k), _fmt_vec(run.get("vertex")), source.replace("_", " ")]
                    + [None if vals.get(c) is None else float(vals[c]) for c in columns]
                )
    return header, rows


#: canonical axis order of the state equations (seed 0 Tables 2-3); other keys keep file order.
AXIS_ORDER = ("u", "v", "w", "p", "q", "r", "phi", "theta", "dt", "da", "de", "dr")


def _axis_key(name: str) -> str:
    n = str(name).lower()
    for suffix in ("_dot", "dot", "'"):
        if n.endswith(suffix) and n[: -len(suffix)] in AXIS_ORDER:
            return n[: -len(suffix)]
    return n


def order_axes(axes: list[str]) -> list[str]:
    """Sort axis keys like udot, vdot, ... (or u, v, ...) in the seed's table order."""

    def rank(a: str) -> tuple[int, int]:
        k = _axis_key(a)
        return (AXIS_ORDER.index(k), 0) if k in AXIS_ORDER else (len(AXIS_ORDER), axes.index(a))

    return sorted(axes, key=rank)


def fit_table(models: dict, metric: str) -> tuple[list[str], list[list[Any]], bool]:
    """Per-vertex, per-axis ``fit.<metric>`` (Table 2 for r2). Returns (header, rows, percent)
    where R^2 stored as a fraction is shown in percent like the seed."""
    vertices = models.get("vertices") or []
    axes: list[str] = []
    for vx in vertices:
        m = ((vx.get("fit") or {}).get(metric) or {}) if isinstance(vx, dict) else {}
        if isinstance(m, dict):
            axes += [a for a in m if a not in axes]
    if not axes:
        return [], [], False
    axes = order_axes(axes)
    values = [[((vx.get("fit") or {}).get(metric) or {}).get(a) for a in axes] for vx in vertices]
    flat = [float(v) for row in values for v in row if isinstance(v, (int, float))]
    percent = metric == "r2" and bool(flat) and max(abs(v) for v in flat) <= 1.0
    rows = []
    for vx, vals in zip(vertices, values):
        rows.append(
            [_fmt_vec(vx.get("scheduling"))]
            + [None if v is None else float(v) * (100.0 if percent else 1.0) for v in vals]
        )
    return ["vertex [m/s]"] + axes, rows, percent


def validation_table(validation: dict) -> tuple[list[str], list[list[Any]]]:
    """Seed 0 Table 3 from ``validation.yaml``: {tic: {axis: x}, nrmse: {axis: x}}."""
    axes: list[str] = []
    for m in ("tic", "nrmse"):
        block = validation.get(m) or validation.get(m.upper()) or {}
        if isinstance(block, dict):
            axes += [a for a in block if a not in axes]
    if not axes:
        raise ConfigError("validation.yaml: expected 'tic' and/or 'nrmse' mappings axis -> value")
    axes = order_axes(axes)
    rows = []
    for m in ("tic", "nrmse"):
        block = validation.get(m) or validation.get(m.upper()) or {}
        rows.append(
            [m.upper()] + [None if block.get(a) is None else float(block[a]) for a in axes]
        )
    return ["metric"] + axes, rows


def _fmt_vec(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + " ".join(f"{float(x):+g}" for x in v) + "]"
    return str(v)
