"""A phase-1 campaign's bags -> the vertex models (seed 0 Sec. IV, Tables 1-3).

Every bag is one maneuver: aligned (:mod:`~lpv_sysid.ident.dataprep`), its scheduling
snapped to the box corner it was flown at, the one at the box centre kept as the
validation maneuver; each vertex of the box must be flown once. The vertices are
identified by equation error (:mod:`~lpv_sysid.ident.vertex`), with in-sample metrics, in
the box's vertex order, and validated on the centre maneuver when there is one.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.ident import dataprep as dp
from lpv_sysid.ident import vertex as vx


@dataclass
class Phase1Identification:
    """The identified vertices (box order), the validation on the centre maneuver (None
    without one) and notes on how the data were read (one line each)."""

    results: list
    validation: Optional[dict[str, Any]]
    notes: list[str] = field(default_factory=list)


def identify_campaign(bags_path: str, cfg: vx.IdentificationConfig) -> Phase1Identification:
    """Identify the vertex models of the phase-1 bags under ``bags_path`` with ``cfg``;
    ConfigError naming the bag for a second maneuver at a vertex or at the centre, and the
    vertices no bag flew."""
    bags = dp.find_bags(bags_path)
    centre = 0.5 * (np.asarray(cfg.vmin) + np.asarray(cfg.vmax))
    vertices: dict[tuple[float, ...], vx.VertexData] = {}
    validation = None
    notes: list[str] = []
    for bag in bags:
        aligned = dp.align(dp.streams_from_bag(bag), cfg)
        v_d = dp.snap_to_box(aligned.vertex.scheduling, cfg)
        data = dataclasses.replace(aligned.vertex, scheduling=v_d)
        if np.allclose(v_d, centre):
            if validation is not None:
                raise ConfigError(
                    f"{bag}: second validation maneuver at the box centre "
                    f"(first: {validation.name})"
                )
            validation = data
            continue
        key = tuple(v_d)
        if key in vertices:
            raise ConfigError(f"{bag}: vertex {list(key)} already given by {vertices[key].name}")
        if aligned.input_source != "actuator_command":
            notes.append(
                f"{bag.name}: no actuator_command, input reconstructed from rotor speeds (Eq. 8)"
            )
        vertices[key] = data
    missing = [c.tolist() for c in vx.box_corners(cfg) if tuple(c) not in vertices]
    if missing:
        raise ConfigError(f"{bags_path}: no maneuver for vertex/vertices {missing}")
    datas = list(vertices.values())
    results = vx.identify_vertices(datas, cfg)
    results = [
        dataclasses.replace(res, validation=vx.in_sample_metrics(res, data, cfg))
        for res, data in zip(results, datas)
    ]
    results = [results[k] for k in vx.vertex_order(results, cfg)]
    val = None
    if validation is not None:
        val = vx.validate(results, validation, cfg)
        val["name"] = validation.name
        val["output_error"] = vx.free_run(results, validation, cfg)
    return Phase1Identification(results, val, notes)
