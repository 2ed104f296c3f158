"""``gains.yaml`` (``lpv_sysid/gains@1``): the certified gain schedule, strictly validated.

Vertex gains ``K_i`` (seed 0 Eq. 31, ``du_c = K dx``) with the vertex equilibria, excitation
input matrix ``R`` (Eq. 27), performance scaling ``Q`` (Eq. 28), the bound ``gamma`` and the
``certificate`` (:mod:`lpv_sysid.io.formats.certificate`). Optional reference feedforward
(:mod:`lpv_sysid.synthesis.feedforward`): a top-level ``feedforward: {free_states,
accelerated_states, held_states}`` and, then required at every vertex, ``F_ff`` with
``len(free_states) + n_u`` rows (free states in the listed order, then the inputs) and one
column per accelerated state; with ``kinematic_states`` and ``rate_states`` in ``feedforward``
also ``F_jerk`` (rows: free states, inputs, rate states; the jerk term). A file without
``feedforward`` has no feedforward (older files).

:class:`GainSchedule` is the one reading of a gains file: the runtime law
(:class:`lpv_sysid.control.law.controller.LpvController`), ``lpv-sysid verify``, replay and
the simulations all load it through :meth:`GainSchedule.load`, which also requires the law to
hash to ``certificate.gains_sha256`` and the whole file to match its ``seal``
(:mod:`lpv_sysid.io.formats.seal`: every entry but the seal, optionally keyed with an operator
key). Channel lists, time base, box and vertex order: :mod:`lpv_sysid.io.formats.shared`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.files import read_located, save_yaml, sha256_file
from lpv_sysid.io.formats.certificate import Certificate
from lpv_sysid.io.formats.feedforward_spec import FeedforwardSpec
from lpv_sysid.io.formats.field_checker import FieldChecker, kind_of, rows
from lpv_sysid.io.formats.gain_vertex import GainVertex
from lpv_sysid.io.formats.seal import check_seal, seal_document
from lpv_sysid.io.formats.shared import (
    QUADROTOR_LAYOUT,
    Layout,
    SchedulingBox,
    StackedVertices,
    layout_of,
    order_vertices,
    parse_channels,
    parse_time,
    time_dict,
)
from lpv_sysid.io.formats.vertex_models import VertexModels

if TYPE_CHECKING:
    from lpv_sysid.models.lpv import PolytopicModel


GAINS_FORMAT = "lpv_sysid/gains@1"


@dataclass(frozen=True)
class GainSchedule(StackedVertices):
    """Contents of ``gains.yaml``; ``vertices`` in box order."""

    state_names: tuple
    state_units: tuple
    input_names: tuple
    input_units: tuple
    scheduling: SchedulingBox
    vertices: tuple
    R: np.ndarray
    Q: np.ndarray
    gamma: float
    certificate: Certificate
    ts: Optional[float] = None
    feedforward: Optional[FeedforwardSpec] = None

    @property
    def F_ff(self) -> Optional[np.ndarray]:
        """Stacked feedforward matrices (N, n_free + m, p) in box order, or None."""
        if self.feedforward is None:
            return None
        return self._stacked("F_ff")

    @property
    def F_jerk(self) -> Optional[np.ndarray]:
        """Stacked jerk-term matrices (N, n_free + m + n_rate, p) in box order, or None."""
        if self.feedforward is None or not self.feedforward.has_jerk:
            return None
        return self._stacked("F_jerk")

    @property
    def K(self) -> np.ndarray:
        """Stacked gains (N, m, n) in box order."""
        return self._stacked("K")

    @property
    def vmin(self) -> np.ndarray:
        """Lower corner of the scheduling box (``scheduling.min``)."""
        return self.scheduling.min

    @property
    def vmax(self) -> np.ndarray:
        """Upper corner of the scheduling box (``scheduling.max``)."""
        return self.scheduling.max

    def law_sha256(self) -> str:
        """SHA-256 of the law the runtime flies: channel and scheduling names, the box, the
        time base, per vertex (box order) K, x0, u0 (and F_ff, F_jerk with their layout),
        R, Q and gamma, as float64 bytes (a YAML round trip keeps every bit). The certifying
        tool writes it to ``certificate.gains_sha256`` (:func:`certify_law`); the runtime
        refuses a file whose law no longer hashes to it."""
        h = hashlib.sha256(b"lpv_sysid/gains-law@1")

        def put(tag: str, a) -> None:
            a = np.ascontiguousarray(np.asarray(a, dtype="<f8"))
            h.update(f"|{tag}{a.shape}|".encode())
            h.update(a.tobytes())

        h.update(repr((self.state_names, self.input_names, self.scheduling.names)).encode())
        put("min", self.scheduling.min)
        put("max", self.scheduling.max)
        put("ts", [] if self.ts is None else [self.ts])
        for name in ("K", "x0", "u0"):
            put(name, getattr(self, name))
        put("R", self.R)
        put("Q", self.Q)
        put("gamma", [self.gamma])
        if self.feedforward is not None:
            h.update(repr(sorted(self.feedforward.to_dict().items())).encode())
            put("F_ff", self.F_ff)
            if self.F_jerk is not None:
                put("F_jerk", self.F_jerk)
        return h.hexdigest()

    def check_law_sha256(self, label: str = "gains.yaml") -> None:
        """ConfigError unless ``certificate.gains_sha256`` is present and equals
        :meth:`law_sha256` (the gains flown are the gains that were certified)."""
        v = FieldChecker(label)
        got = self.certificate.gains_sha256
        if got is None:
            v.fail(
                "certificate.gains_sha256",
                "missing: the file does not record which gains "
                "were certified (written before this check existed); re-run `lpv-sysid "
                "synthesize` to regenerate the gains and their certificate",
            )
        if got != self.law_sha256():
            v.fail(
                "certificate.gains_sha256",
                f"{got} does not match the gains in the file "
                f"(sha256 {self.law_sha256()}): K, x0, u0, R, Q, gamma or the feedforward "
                "were changed after certification; re-run `lpv-sysid synthesize` (and "
                "`lpv-sysid verify`) instead of editing gains",
            )

    def to_dict(self) -> dict:
        d: dict[str, Any] = {"format": GAINS_FORMAT}
        if self.ts is not None:
            d["time"] = time_dict(self.ts)
        d.update(
            {
                "states": [
                    {"name": n, "unit": u} for n, u in zip(self.state_names, self.state_units)
                ],
                "inputs": [
                    {"name": n, "unit": u} for n, u in zip(self.input_names, self.input_units)
                ],
                "scheduling": self.scheduling.to_dict(),
                "vertices": [vx.to_dict() for vx in self.vertices],
                "R": rows(self.R),
                "Q": rows(self.Q),
                "gamma": float(self.gamma),
                "certificate": self.certificate.to_dict(),
            }
        )
        if self.feedforward is not None:
            d["feedforward"] = self.feedforward.to_dict()
        return d

    @classmethod
    def from_dict(
        cls, d, layout: Optional[Layout] = QUADROTOR_LAYOUT, label: str = "gains.yaml"
    ) -> "GainSchedule":
        v = FieldChecker(label)
        lay = layout or Layout()
        v.mapping(
            d,
            "",
            (
                "format",
                "states",
                "inputs",
                "scheduling",
                "vertices",
                "R",
                "Q",
                "gamma",
                "certificate",
            ),
            ("time", "feedforward", "seal"),
        )
        if d["format"] != GAINS_FORMAT:
            v.fail("format", f"expected {GAINS_FORMAT!r}, got {d['format']!r}")
        ts = parse_time(v, d["time"]) if "time" in d else None
        sn, su = parse_channels(v, d["states"], "states", lay.state_names, lay.state_units)
        inn, inu = parse_channels(v, d["inputs"], "inputs", lay.input_names, lay.input_units)
        box = SchedulingBox.parse(v, d["scheduling"], lay.scheduling_names)
        n_x, n_u, n_p = len(sn), len(inn), len(box.names)
        if not isinstance(d["vertices"], list):
            v.fail("vertices", f"expected a list, got {kind_of(d['vertices'])}")
        ff = None
        if d.get("feedforward") is not None:
            ff = FeedforwardSpec.parse(v, d["feedforward"], sn, n_u, n_p)
        ff_shape = None if ff is None else ff.shape(n_u)
        jerk_shape = None if ff is None else ff.jerk_shape(n_u)
        vxs = [
            GainVertex.parse(v, e, i, n_x, n_u, n_p, ff_shape, jerk_shape)
            for i, e in enumerate(d["vertices"])
        ]
        order = order_vertices(v, [vx.scheduling for vx in vxs], box)
        R = v.matrix(d["R"], (n_u, n_u), "R")
        Q = v.matrix(d["Q"], (n_p, n_p), "Q")
        if abs(np.linalg.det(Q)) < 1e-12 * max(1.0, np.abs(Q).max()) ** n_p:
            v.fail("Q", "must be invertible (z = Q^-1 (v - v_d), seed 0 Eq. 28)")
        gamma = v.number(d["gamma"], "gamma")
        if gamma <= 0:
            v.fail("gamma", f"must be > 0, got {gamma}")
        cert = Certificate.parse(v, d["certificate"], n_p=n_p, n_e=R.shape[1])
        if cert.gamma_achieved > gamma * (1 + 1e-6):
            v.fail("certificate.gamma_achieved", f"{cert.gamma_achieved} exceeds gamma = {gamma}")
        return cls(sn, su, inn, inu, box, tuple(vxs[k] for k in order), R, Q, gamma, cert, ts, ff)

    @classmethod
    def load(
        cls,
        path,
        models_path=None,
        layout: Optional[Layout] = QUADROTOR_LAYOUT,
        *,
        auto_layout: bool = False,
        key: Optional[bytes] = None,
    ) -> "GainSchedule":
        """Read (once) and validate, then the law against ``certificate.gains_sha256``
        (:meth:`check_law_sha256`) and the whole file against its seal
        (:func:`~lpv_sysid.io.formats.seal.check_seal`; with ``key``, the operator's keyed
        seal too); with ``models_path`` also check it against the models file
        (:meth:`check_models`). ``auto_layout``: the layout :func:`layout_of` picks from the
        gains document (the quadrotor's when it names the quadrotor's states, else none), also
        used for the models file."""
        path = Path(path)
        doc = read_located(path)
        if auto_layout:
            layout = layout_of(doc)
        gs = cls.from_dict(doc, layout, label=path.name)
        gs.check_law_sha256(path.name)
        check_seal(doc, path.name, key)
        if models_path is not None:
            models = VertexModels.load(models_path, layout)
            gs.check_models(
                models,
                sha256_file(models_path),
                label=path.name,
                models_label=Path(models_path).name,
            )
        return gs

    def check_models(
        self,
        models: VertexModels,
        models_sha256: Optional[str] = None,
        label: str = "gains.yaml",
        models_label: str = "vertex_models.yaml",
        rtol: float = 1e-9,
    ) -> None:
        """Refuse gains synthesised for other models: names, units, box, time base, vertex
        equilibria and (when given) the models file's SHA-256."""
        v = FieldChecker(label)
        for what, mine, theirs in (
            (
                "states",
                (self.state_names, self.state_units),
                (models.state_names, models.state_units),
            ),
            (
                "inputs",
                (self.input_names, self.input_units),
                (models.input_names, models.input_units),
            ),
        ):
            if mine != theirs:
                v.fail(
                    what,
                    f"names/units {list(zip(*mine))} differ from {models_label} "
                    f"{list(zip(*theirs))}",
                )
        if not self.scheduling.same_as(models.scheduling):
            v.fail(
                "scheduling",
                f"box {self.scheduling.to_dict()} differs from {models_label} "
                f"{models.scheduling.to_dict()}",
            )
        if self.ts != models.ts:
            v.fail(
                "time",
                f"{time_dict(self.ts)!r} differs from {models_label} {time_dict(models.ts)!r}",
            )
        for i, (g, m) in enumerate(zip(self.vertices, models.vertices)):
            for name in ("x0", "u0"):
                a, b = getattr(g, name), getattr(m, name)
                if not np.allclose(a, b, rtol=rtol, atol=rtol):
                    v.fail(
                        f"vertices[{i}].{name}",
                        f"differs from {models_label} vertices[{i}].{name} "
                        f"(max |diff| {np.max(np.abs(a - b)):.3g})",
                    )
        if models_sha256 is not None and models_sha256 != self.certificate.models_sha256:
            v.fail(
                "certificate.models_sha256",
                f"{self.certificate.models_sha256} does not match "
                f"{models_label} (sha256 {models_sha256})",
            )

    def save(self, path, key: Optional[bytes] = None) -> None:
        """Write the file, sealed (with ``key``: the keyed seal too)."""
        doc = self.to_dict()
        self.from_dict(doc, layout=None, label=Path(path).name)  # never write an invalid file
        save_yaml(seal_document(doc, key), path)


def certify_law(
    doc: dict,
    layout: Optional[Layout] = None,
    label: str = "gains.yaml",
    key: Optional[bytes] = None,
) -> dict:
    """``doc`` (a gains.yaml mapping) with ``certificate.gains_sha256`` set to the
    :meth:`GainSchedule.law_sha256` of the law it holds, then sealed as a whole
    (:func:`~lpv_sysid.io.formats.seal.seal_document`; with ``key`` also the operator's keyed
    seal). Called only by the tool that certified that law (``lpv-sysid synthesize``; the
    LQR test-law writer of the tests), never by a loader or editor: the hash records what
    was certified, the seal the file that was written (anyone can recompute an unkeyed seal;
    only a key holder a keyed one)."""
    gs = GainSchedule.from_dict(doc, layout, label)
    body = {k: v for k, v in doc.items() if k != "seal"}
    certified = {**body, "certificate": {**doc["certificate"], "gains_sha256": gs.law_sha256()}}
    return seal_document(certified, key)


def gains_dict(
    models_raw: Mapping,
    model: "PolytopicModel",
    K: np.ndarray,
    R: np.ndarray,
    Q: np.ndarray,
    gamma: float,
    certificate: dict,
    F_ff: Optional[np.ndarray] = None,
    ff_layout: Optional[dict] = None,
    F_jerk: Optional[np.ndarray] = None,
    seal_key: Optional[bytes] = None,
) -> dict:
    """The certified gains.yaml document of a synthesis result: channels and box from the
    models document ``models_raw``, per vertex (box order of ``model``) K, x0, u0, the weights,
    ``gamma`` and the ``certificate`` mapping, with ``certificate.gains_sha256`` set to the hash
    of this law (:func:`certify_law`, which validates the document).

    With ``F_ff`` (N, n_free + m, p) and its layout (``FeedforwardLayout.to_dict()``) every vertex
    gets an ``F_ff`` entry and the document a top-level ``feedforward`` (synthesis/feedforward.py).
    The document is sealed (``seal_key``: with the operator's keyed seal too).
    """
    d = {
        "format": GAINS_FORMAT,
        "states": models_raw["states"],
        "inputs": models_raw["inputs"],
        "scheduling": models_raw["scheduling"],
        "vertices": [
            {
                "scheduling": model.vertices[i].tolist(),
                "K": np.asarray(K[i]).tolist(),
                "x0": model.x0[i].tolist(),
                "u0": model.u0[i].tolist(),
            }
            for i in range(model.n_vertices)
        ],
        "R": np.asarray(R).tolist(),
        "Q": np.asarray(Q).tolist(),
        "gamma": float(gamma),
        "certificate": certificate,
    }
    if F_ff is not None:
        if ff_layout is None:
            raise ConfigError("gains_dict: F_ff needs its layout (free/accelerated/held states)")
        d["feedforward"] = dict(ff_layout)
        for i, vx in enumerate(d["vertices"]):
            vx["F_ff"] = np.asarray(F_ff[i]).tolist()
            if F_jerk is not None:
                vx["F_jerk"] = np.asarray(F_jerk[i]).tolist()
    # the hash of the law just certified (the one place it is written; io.formats.certify_law)
    return certify_law(d, layout=None, label="gains", key=seal_key)
