"""The versioned files between identification, synthesis and flight: one owner per format.

Each module reads (once), validates strictly and writes one file format; everyone else loads
through it (the synthesis, ``verify``, the flight runtime, replay and the simulations get the
same reading of the same bytes):

========================================  ===================================================
:mod:`~lpv_sysid.io.formats.vertex_models`  ``vertex_models.yaml`` (:class:`VertexModels`)
:mod:`~lpv_sysid.io.formats.export`         its export: ``.mat`` file, python-control systems
:mod:`~lpv_sysid.io.formats.gains`          ``gains.yaml`` (:class:`GainSchedule`)
:mod:`~lpv_sysid.io.formats.certificate`    its ``certificate`` entry (:class:`Certificate`)
:mod:`~lpv_sysid.io.formats.seal`           its ``seal`` (whole file; optional operator key)
:mod:`~lpv_sysid.io.formats.sidecar`        the certificate sidecar ``<gains>.cert.npz``
:mod:`~lpv_sysid.io.formats.shared`         channels, time base, scheduling box, vertex order
:mod:`~lpv_sysid.io.formats.field_checker`  the field-path checks the formats are written with
========================================  ===================================================

Validation is strict: format tag, unknown/missing keys, names and units (by default the
quadrotor layout of :mod:`lpv_sysid.models.quadrotor`), matrix shapes, finiteness, the box
(``min < max``; the vertices are exactly the 2^p corners, each once) and the uncertain
entries. Every error is a :class:`~lpv_sysid.errors.ConfigError` whose message starts with
the file name and the field path, e.g. ``gains.yaml: vertices[3].K: expected shape 4x12,
got 4x11``. The YAML itself is read and written by :mod:`lpv_sysid.io.files.yaml_reader`, hashes by
:mod:`lpv_sysid.io.files.hashing`.

Signal files (``signals.npz``, ``summary.yaml``) are owned by
:mod:`lpv_sysid.signals.store`.
"""

from __future__ import annotations

from lpv_sysid.io.formats.certificate import DesignEnvelope
from lpv_sysid.io.formats.export import (
    MAT_FORMAT,
    control_systems,
    models_mat_dict,
    save_models_mat,
)
from lpv_sysid.io.formats.feedforward_spec import FeedforwardSpec
from lpv_sysid.io.formats.gains import GAINS_FORMAT, GainSchedule, certify_law, gains_dict
from lpv_sysid.io.formats.seal import check_seal, load_seal_key, seal_document
from lpv_sysid.io.formats.sidecar import (
    box_arrays,
    load_certificate_npz,
    load_certified_systems,
    referenced_files,
    save_certificate_npz,
    systems_arrays,
)
from lpv_sysid.io.formats.vertex_models import (
    MODELS_FORMAT,
    MODELS_FORMAT_V1,
    UncertainEntry,
    VertexModel,
    VertexModels,
    models_dict,
)

__all__ = [
    "DesignEnvelope",
    "FeedforwardSpec",
    "GAINS_FORMAT",
    "GainSchedule",
    "MAT_FORMAT",
    "MODELS_FORMAT",
    "MODELS_FORMAT_V1",
    "UncertainEntry",
    "VertexModel",
    "VertexModels",
    "box_arrays",
    "certify_law",
    "check_seal",
    "control_systems",
    "gains_dict",
    "load_certificate_npz",
    "load_certified_systems",
    "load_seal_key",
    "models_dict",
    "models_mat_dict",
    "referenced_files",
    "save_certificate_npz",
    "save_models_mat",
    "seal_document",
    "systems_arrays",
]
