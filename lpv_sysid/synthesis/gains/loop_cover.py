"""Gains whose certificate covers the loop that will fly them (``lpv-sysid synthesize
--loop-delay S``, the chain's step 4).

The certified loop delay (``certificate.loop_delay.bound_s``, :mod:`lpv_sysid.synthesis.delay`)
is a property of the identified plant and the synthesized gains: on PX4 SIH airframes it was
45.6-84.0 ms with the chain's pole region (2026-12-03), against the 60 ms loop of
``config/lpv_controller_px4.yaml``, whose start-up check refuses gains below it. A slower
closed loop tolerates more delay: :func:`cover_loop` synthesizes with the configured region
first and, while the proven bound is below the loop, again with the region's disk (seed 2
Eq. 125, ``hinf.region.disk``: centre and radius) scaled by :data:`REGION_SCALES` -- smaller
poles, smaller gains, a larger margin (48.2 -> 58.6 -> 73.2 ms on an airframe with
SIH_T_TAU 0.1 s). Every attempt is an ordinary synthesis with its own independent
verification; the configuration actually used is written beside the gains.

Example (any ``attempt`` that writes and verifies gains from a config file)::

    >>> ok, tried = cover_loop(cfg, used, 0.060, attempt)   # doctest: +SKIP
    >>> [(a["region_scale"], a["loop_delay_bound_s"]) for a in tried]   # doctest: +SKIP
    [(1.0, 0.0482), (0.8, 0.0586), (0.64, 0.0732)]
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Callable

import yaml

#: disk scales tried in turn (1.0: the configuration as given)
REGION_SCALES = (1.0, 0.8, 0.64, 0.5, 0.4)


def scaled_region(doc: dict, scale: float) -> dict:
    """A copy of the synthesis config ``doc`` with ``hinf.region.disk`` centre and radius
    times ``scale`` (the half-plane and everything else unchanged)."""
    out = copy.deepcopy(doc)
    if scale != 1.0:
        disk = out["hinf"]["region"]["disk"]
        disk["centre"] = float(disk["centre"]) * scale
        disk["radius"] = float(disk["radius"]) * scale
    return out


def cover_loop(
    config: str | Path,
    used: str | Path,
    loop_s: float,
    attempt: Callable[[Path], tuple[bool, Path]],
    echo: Callable[[str], None] = lambda _: None,
) -> tuple[bool, list[dict]]:
    """Synthesize through ``attempt(config_path) -> (verified, gains_path)`` until the gains'
    ``certificate.loop_delay.bound_s`` >= ``loop_s`` (module docstring); ``used``: where each
    attempt's configuration is written (the last one stays). A config without a disk region
    is tried once. Returns (the last gains written verified, the attempts: region scale and
    region, verified, bound -- or the error of an attempt that found no gains, which ends the
    search); the last gains written stay when none covers the loop (the controller refuses
    them at start, as it must). An error of the first attempt is raised."""
    from lpv_sysid.errors import LpvSysidError
    from lpv_sysid.io.files import read_yaml_mapping
    from lpv_sysid.io.formats import GainSchedule

    base = read_yaml_mapping(config, finite=False)
    region = (base.get("hinf") or {}).get("region")
    has_disk = isinstance(region, dict) and isinstance(region.get("disk"), dict)
    used = Path(used)
    used.parent.mkdir(parents=True, exist_ok=True)
    attempts: list[dict] = []
    ok = False
    previous: str | None = None
    for scale in REGION_SCALES if has_disk else REGION_SCALES[:1]:
        doc = scaled_region(base, scale)
        text = yaml.safe_dump(doc, sort_keys=False)
        used.write_text(text)
        try:
            ok, gains = attempt(used)
        except LpvSysidError as exc:
            if previous is None:
                raise
            # e.g. Lemma 1 infeasible at gamma in the smaller region: nothing was written,
            # the previous attempt's gains stay, and so does the config that made them
            used.write_text(previous)
            attempts.append(
                {
                    "region_scale": scale,
                    "region": doc["hinf"].get("region"),
                    "error": str(exc).split(" | ")[0],
                }
            )
            echo(f"region x{scale:g}: {attempts[-1]['error']}; the previous gains stay")
            break
        previous = text
        bound = GainSchedule.load(str(gains), auto_layout=True).certificate.loop_delay_bound_s
        bound = float(bound) if bound is not None else 0.0
        attempts.append(
            {
                "region_scale": scale,
                "region": doc["hinf"].get("region"),
                "verified": bool(ok),
                "loop_delay_bound_s": bound,
            }
        )
        echo(
            f"region x{scale:g}: certified loop delay {bound * 1e3:.1f} ms, loop "
            f"{loop_s * 1e3:.1f} ms{'' if bound >= loop_s else ' (not covered)'}"
        )
        if not ok or bound >= loop_s:
            break
    return ok, attempts
