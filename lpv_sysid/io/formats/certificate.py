"""The ``certificate`` entry of ``gains.yaml``: what the synthesis proved and for which file.

:class:`Certificate`: the bound of seed 0 Lemma 1 (``lmi``, ``solver``, ``gamma_achieved``,
``min_margin``), ``models_sha256`` = SHA-256 of the bytes of the models file the gains were
synthesised for, ``gains_sha256`` = the hash of the certified law
(:meth:`lpv_sysid.io.formats.gains.GainSchedule.law_sha256`), ``design`` = the phase-2 signal
envelope the gains were designed for (:class:`DesignEnvelope`) and ``sidecar`` = the
certificate sidecar holding the certified systems (:mod:`lpv_sysid.io.formats.sidecar`), all
three required by the flight runtime; ``certified_set`` (written by ``lpv-sysid synthesize``,
docs/certificate.md) says exactly which plants and which scheduling signals the bound covers:
``kind`` (``full_identified_box``: every element of the models file in its interval, the box
itself in the sidecar; ``reduced_polytope``: the convex hull of the sidecar's Eq. (23) systems)
and ``scheduling.variation`` (``frozen`` v_d, ``arbitrary`` rate: one Lyapunov matrix, or
``rate_bounded`` with ``rate_bound``); the systems the runtime re-checks (sidecar ``A_sys``,
``B_sys``) are members of that set; ``loop_delay`` (:class:`LoopDelay`, accessor
:attr:`Certificate.loop_delay_bound_s`) the constant loop delay the proof covers. Other keys
the synthesis records (``uncertainty``, ``input_structure``, ``region``, ...) are kept in
:attr:`Certificate.extra`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from lpv_sysid.io.formats.field_checker import FieldChecker, floats


@dataclass(frozen=True)
class DesignEnvelope:
    """``certificate.design``: the phase-2 signal the gains were designed for (written by
    ``lpv-sysid synthesize`` from the signals summary;
    :func:`lpv_sysid.signals.excitation.design_envelope`).

    The runtime bounds what it follows by it: ``reference_peak`` |v_d| per scheduling axis
    [m/s], ``reference_rate`` |dv_d/dt| [m/s^2] and ``reference_accel`` |d2v_d/dt2| [m/s^3]
    (Bernstein bounds of the band-limited table), ``knot_interval_s`` the table's sample
    interval (the played v_d is linear between samples), ``fade_s`` the shortest raised-cosine
    fade (excitation node ``ramp_s``) the rate and acceleration bounds include,
    ``excitation_peak`` |u_e| per excitation channel (normalised, Eq. 26), ``source`` where it
    came from."""

    reference_peak: tuple
    reference_rate: tuple
    reference_accel: tuple
    knot_interval_s: float
    fade_s: float
    excitation_peak: tuple
    source: str = ""

    KEYS = (
        "reference_peak",
        "reference_rate",
        "reference_accel",
        "knot_interval_s",
        "fade_s",
        "excitation_peak",
    )

    def to_dict(self) -> dict:
        return {
            "reference_peak": list(self.reference_peak),
            "reference_rate": list(self.reference_rate),
            "reference_accel": list(self.reference_accel),
            "knot_interval_s": float(self.knot_interval_s),
            "fade_s": float(self.fade_s),
            "excitation_peak": list(self.excitation_peak),
            "source": self.source,
        }

    @classmethod
    def parse(
        cls,
        v: FieldChecker,
        d,
        n_p: Optional[int],
        n_e: Optional[int],
        path: str = "certificate.design",
    ) -> "DesignEnvelope":
        v.mapping(d, path, cls.KEYS, ("source",))
        out = {}
        for key, n in (
            ("reference_peak", n_p),
            ("reference_rate", n_p),
            ("reference_accel", n_p),
            ("excitation_peak", n_e),
        ):
            vec = v.vector(d[key], n, f"{path}.{key}")
            if np.any(vec <= 0):
                v.fail(f"{path}.{key}", f"entries must be > 0, got {floats(vec)}")
            out[key] = tuple(floats(vec))
        knot = v.number(d["knot_interval_s"], f"{path}.knot_interval_s")
        if not knot > 0:
            v.fail(f"{path}.knot_interval_s", f"must be > 0, got {knot}")
        fade = v.number(d["fade_s"], f"{path}.fade_s")
        if not fade > 0:
            v.fail(f"{path}.fade_s", f"must be > 0, got {fade}")
        source = v.string(d.get("source", ""), f"{path}.source", nonempty=False)
        return cls(
            out["reference_peak"],
            out["reference_rate"],
            out["reference_accel"],
            knot,
            fade,
            out["excitation_peak"],
            source,
        )


@dataclass(frozen=True)
class LoopDelay:
    """``certificate.loop_delay`` (issue 20 item 7): the constant state -> command -> actuator
    delay ``bound_s`` [s] up to which the proof holds (D-scaled small gain on the frozen loops,
    :mod:`lpv_sysid.synthesis.delay`), the proven margins and what the proof covers. The flight
    controller refuses a configured loop (rate, state rate, measured input latency) whose worst
    delay exceeds ``bound_s``."""

    bound_s: float
    stability_margin_s: Optional[float] = None
    performance_margin_s: Optional[float] = None
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d: dict = {"bound_s": float(self.bound_s)}
        for k in ("stability_margin_s", "performance_margin_s"):
            if getattr(self, k) is not None:
                d[k] = float(getattr(self, k))
        d.update(self.extra)
        return d

    @classmethod
    def parse(cls, v: FieldChecker, d, path: str = "certificate.loop_delay") -> "LoopDelay":
        v.mapping(d, path, ("bound_s",), extra_ok=True)
        bound = v.number(d["bound_s"], f"{path}.bound_s")
        if not (np.isfinite(bound) and bound > 0):
            v.fail(f"{path}.bound_s", f"must be a finite number > 0 [s], got {bound}")
        margins = {}
        for k in ("stability_margin_s", "performance_margin_s"):
            margins[k] = None if d.get(k) is None else v.number(d[k], f"{path}.{k}")
        pm = margins["performance_margin_s"]
        if pm is not None and bound > pm * (1 + 1e-9):
            v.fail(f"{path}.bound_s", f"{bound} s exceeds the proven performance margin {pm} s")
        own = ("bound_s", "stability_margin_s", "performance_margin_s")
        return cls(
            bound,
            margins["stability_margin_s"],
            pm,
            {k: d[k] for k in d if k not in own},
        )


#: ``certificate.certified_set.kind`` / ``.scheduling.variation`` (module docstring)
CERTIFIED_SET_KINDS = ("full_identified_box", "reduced_polytope")
SCHEDULING_VARIATIONS = ("frozen", "arbitrary", "rate_bounded")


@dataclass(frozen=True)
class Certificate:
    """What the synthesis proved (seed 0 Lemma 1) and for which models file.

    ``gains_sha256``: :meth:`GainSchedule.law_sha256` of the law that was certified (written
    once, by the tool that certified it); ``design``: the :class:`DesignEnvelope`."""

    lmi: str
    solver: str
    gamma_achieved: float
    min_margin: float
    models_sha256: str
    extra: dict = field(default_factory=dict)
    gains_sha256: Optional[str] = None
    design: Optional[DesignEnvelope] = None
    loop_delay: Optional[LoopDelay] = None

    @property
    def loop_delay_bound_s(self) -> Optional[float]:
        """``certificate.loop_delay.bound_s`` [s]: the largest constant loop delay the proof
        covers (None: a certificate written before the delay was certified)."""
        return None if self.loop_delay is None else float(self.loop_delay.bound_s)

    def to_dict(self) -> dict:
        d = {
            "lmi": self.lmi,
            "solver": self.solver,
            "gamma_achieved": float(self.gamma_achieved),
            "min_margin": float(self.min_margin),
            "models_sha256": self.models_sha256,
        }
        d.update(self.extra)
        if self.gains_sha256 is not None:
            d["gains_sha256"] = self.gains_sha256
        if self.design is not None:
            d["design"] = self.design.to_dict()
        if self.loop_delay is not None:
            d["loop_delay"] = self.loop_delay.to_dict()
        return d

    @staticmethod
    def _sha(v: FieldChecker, x, path: str) -> str:
        sha = v.string(x, path)
        if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            v.fail(path, f"expected 64 lowercase hex digits, got {sha!r}")
        return sha

    @classmethod
    def parse(
        cls,
        v: FieldChecker,
        d,
        path: str = "certificate",
        n_p: Optional[int] = None,
        n_e: Optional[int] = None,
    ) -> "Certificate":
        req = ("lmi", "solver", "gamma_achieved", "min_margin", "models_sha256")
        own = req + ("gains_sha256", "design", "loop_delay")
        v.mapping(d, path, req, extra_ok=True)
        sha = cls._sha(v, d["models_sha256"], f"{path}.models_sha256")
        g = v.number(d["gamma_achieved"], f"{path}.gamma_achieved")
        if g <= 0:
            v.fail(f"{path}.gamma_achieved", f"must be > 0, got {g}")
        gains_sha = (
            cls._sha(v, d["gains_sha256"], f"{path}.gains_sha256")
            if d.get("gains_sha256") is not None
            else None
        )
        design = (
            DesignEnvelope.parse(v, d["design"], n_p, n_e, f"{path}.design")
            if d.get("design") is not None
            else None
        )
        loop_delay = (
            LoopDelay.parse(v, d["loop_delay"], f"{path}.loop_delay")
            if d.get("loop_delay") is not None
            else None
        )
        cs = d.get("certified_set")
        if cs is not None:
            v.mapping(
                cs, f"{path}.certified_set", ("kind", "statement", "scheduling"), extra_ok=True
            )
            if cs["kind"] not in CERTIFIED_SET_KINDS:
                v.fail(
                    f"{path}.certified_set.kind",
                    f"expected one of {CERTIFIED_SET_KINDS}, got {cs['kind']!r}",
                )
            v.mapping(
                cs["scheduling"], f"{path}.certified_set.scheduling", ("variation",), extra_ok=True
            )
            if cs["scheduling"]["variation"] not in SCHEDULING_VARIATIONS:
                v.fail(
                    f"{path}.certified_set.scheduling.variation",
                    f"expected one of {SCHEDULING_VARIATIONS}, "
                    f"got {cs['scheduling']['variation']!r}",
                )
        return cls(
            v.string(d["lmi"], f"{path}.lmi"),
            v.string(d["solver"], f"{path}.solver"),
            g,
            v.number(d["min_margin"], f"{path}.min_margin"),
            sha,
            {k: d[k] for k in d if k not in own},
            gains_sha,
            design,
            loop_delay,
        )
