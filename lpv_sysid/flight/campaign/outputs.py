"""Outputs of `lpv-sysid fly phase1`: ``campaign_summary.yaml``, the trim tables, the
``identification.yaml`` for the flight, and the results table printed at the end."""

from __future__ import annotations

import math
from pathlib import Path

from lpv_sysid.errors import ConfigError


def identification_template(path: str) -> dict:
    from lpv_sysid.io.files import read_yaml

    try:
        d = read_yaml(path)
    except ConfigError:
        return {"identification": {}}
    return d if isinstance(d, dict) else {"identification": {}}


def write_outputs(out: Path, summary: dict, c, ident_template: dict, plan, trim_rows, np) -> None:
    import yaml

    from lpv_sysid.sim.phase1 import write_trim_table

    cfg = plan.config
    (out / "campaign_summary.yaml").write_text(yaml.safe_dump(_plain(summary), sort_keys=False))
    rows = trim_rows(c.results)
    if rows:
        write_trim_table(rows, out)
    ident = dict(ident_template)
    sect = dict(ident.get("identification") or {})
    sect["vmin"] = [float(x) for x in cfg.box_min]
    sect["vmax"] = [float(x) for x in cfg.box_max]
    sect["trim_duration"] = float(cfg.trim_s)
    sect["trim_average"] = float(
        min(sect.get("trim_average", cfg.trim_average_s), cfg.trim_average_s)
    )
    ident["identification"] = sect
    (out / "identification.yaml").write_text(
        "# written by `lpv-sysid fly phase1`: the identification config with the campaign's box "
        "and\n"
        f"# trim duration; lpv-sysid identify --bags {out} --config {out / 'identification.yaml'} "
        "--out "
        "vertex_models.yaml\n" + yaml.safe_dump(ident, sort_keys=False)
    )


def _plain(x):
    """YAML-safe copy (numpy scalars/arrays -> Python)."""
    import numpy as np

    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def format_results(summary: dict) -> str:
    lines = [f"campaign {summary.get('result')}: {summary.get('reason') or 'ok'}"]
    hb = summary.get("handback") or {}
    if hb.get("duration_s") is not None:
        lines.append(f"hand-back: {hb['duration_s']:.2f} s -> {hb.get('mode')}")
    lines.append(
        f"{'run':<22} {'bag':<9} {'settle [s]':>10} {'rms u':>7} {'rms v':>7} {'rms w':>7} "
        f"{'rms r':>7}  achieved (command frame) [m/s]"
    )
    bags = summary.get("bags") or {}
    for r in summary.get("runs") or []:
        rms = r.get("tracking_rms") or {}

        def f(k):
            v = rms.get(k)
            return f"{v:7.3f}" if v is not None else f"{'-':>7}"

        st = r.get("settle_time_s")
        settle = f"{st:10.2f}" if st is not None else f"{'-':>10}"
        ach = " ".join(f"{v:+.2f}" for v in r.get("achieved_frame") or [] if v is not None)
        tag = "" if r.get("complete") else f"  INCOMPLETE: {r.get('reason')}"
        bag = bags.get(r["name"], "-")
        lines.append(
            f"{r['name']:<22} {bag:<9} {settle} {f('u')} {f('v')} {f('w')} {f('r')}  {ach}{tag}"
        )
    return "\n".join(lines)
