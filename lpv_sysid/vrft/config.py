"""Configuration of a VRFT run (seed 1 Sec. 3.3): reference model, controller class, filter,
method. The scalar keys are declared once as fields (:mod:`lpv_sysid.configuration.fields`).

YAML layout (config/vrft_example.yaml)::

    reference_model: {poles: [0.9, 0.9]}        # M = diag((1-p)/(z-p)), Eqs. (5.3)/(5.5)
    #   or {diagonal: [{num: [...], den: [...]}, ...]} or {full: [[{num, den}, ...], ...]}
    controller: {basis: pid, terms: [p, i], structure: full}   # or {basis: velocity, order: 1}
    prefilter: none          # none | one_minus_m | {num: [...], den: [...]}
    method: eiv              # ls (Eq. 3.14) | eiv (Eqs. 3.26-3.31) | iv (Sec. 3.3.2, needs y2)
    window: 10               # EIV window l (Eq. 3.26)
    eiv_weight: identity     # identity (pseudo-code step 5) | residual (two-step W of Eq. 3.30)
    discard: 0               # initial samples left out of the regression
    Ts: null                 # sample time [s]; default: spacing of t in the data file
    outer: {reference_model: ..., controller: ..., prefilter: ...}  # optional: cascade, Sec. 3.3.4
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError
from lpv_sysid.vrft.controller_class import ControllerClass, pid_class, velocity_class
from lpv_sysid.vrft.tf import (
    ONE,
    Tf,
    TfMatrix,
    _is_scalar_identity,
    diagonal_model,
    first_order_model,
)

_LOOP = ("reference_model", "controller", "prefilter")
_PREFILTERS = ("none", "one_minus_m")
_STRUCTURES = ("full", "diagonal")


def _tf(d: Any, where: str) -> Tf:
    if not isinstance(d, dict) or set(d) != {"num", "den"}:
        raise ConfigError(
            f"{where}: expected {{num: [...], den: [...]}} (descending powers of z), got {d!r}"
        )
    try:
        return Tf.make(d["num"], d["den"], where)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: coefficients must be numbers ({exc})") from None


def parse_model(d: Any, where: str = "reference_model") -> TfMatrix:
    if not isinstance(d, dict) or len(d) != 1:
        raise ConfigError(f"{where}: give exactly one of poles / diagonal / full")
    ((key, val),) = d.items()
    if key == "poles":
        if not isinstance(val, list) or not val:
            raise ConfigError(f"{where}.poles: expected a non-empty list of numbers")
        try:
            return first_order_model([float(p) for p in val])
        except (TypeError, ValueError):
            raise ConfigError(f"{where}.poles: expected numbers, got {val!r}") from None
    if key == "diagonal":
        if not isinstance(val, list) or not val:
            raise ConfigError(f"{where}.diagonal: expected a non-empty list of {{num, den}}")
        return diagonal_model([_tf(e, f"{where}.diagonal[{i}]") for i, e in enumerate(val)])
    if key == "full":
        if not isinstance(val, list) or not val or not all(isinstance(r, list) for r in val):
            raise ConfigError(f"{where}.full: expected a square list of lists of {{num, den}}")
        return [
            [_tf(e, f"{where}.full[{i}][{j}]") for j, e in enumerate(r)] for i, r in enumerate(val)
        ]
    raise ConfigError(f"{where}: unknown key {key!r}; use poles, diagonal or full")


def _prefilter(v: Any, where: str) -> Any:
    """``none`` (or null), ``one_minus_m`` or ``{num, den}`` (checked as a Tf)."""
    if isinstance(v, dict):
        _tf(v, where)
        return v
    if v is not None and v not in _PREFILTERS:
        raise ConfigError(f"{where}: {v!r}; use none, one_minus_m or {{num, den}}")
    return v or "none"


@dataclass(frozen=True)
class ControllerSpec:
    """The ``controller`` section: the controller class of seed 1 Sec. 3.3 (built by
    :meth:`LoopConfig.controller_class` once n_u and Ts are known). ``structure``: ``full``,
    ``diagonal`` or a 0/1 matrix (n_u x n_y, checked when the class is built)."""

    basis: str = cf.choice("pid", ("pid", "velocity"), "pid (Eq. 3.2) | velocity basis")
    terms: tuple[str, ...] = cf.texts(
        ("p", "i"),
        "pid: distinct terms of p, i, d",
        choices=("p", "i", "d"),
        fold_case=True,
        unique=True,
    )
    order: int = cf.count(1, "velocity: order of the velocity-form basis")
    structure: Any = "full"

    @classmethod
    def from_dict(cls, d: Any, where: str = "controller") -> "ControllerSpec":
        kw = cf.parse_fields(cls, d, where, other_keys=("structure",))
        structure = d.get("structure", "full")
        if isinstance(structure, str) and structure not in _STRUCTURES:
            raise cf.error(
                where, "structure", f"{structure!r}; use full, diagonal or a 0/1 matrix"
            )
        return cls(structure=structure, **kw)


@dataclass(frozen=True)
class LoopConfig:
    """One loop: the reference model M (``reference_model``, Eqs. 5.3/5.5), the controller
    class (``controller``) and the prefilter L (``prefilter``, Eq. 3.12). M and L are
    transfer functions in the grammar of :func:`parse_model` / ``{num, den}``."""

    M: TfMatrix = field(compare=False)
    controller: ControllerSpec = field(compare=False)
    prefilter: Any = "none"

    @classmethod
    def from_dict(cls, d: Any, where: str = "") -> "LoopConfig":
        cf.parse_fields(
            cls, d, where, other_keys=_LOOP, required=("reference_model", "controller")
        )
        M = parse_model(d["reference_model"], cf.join(where, "reference_model"))
        c = ControllerSpec.from_dict(d["controller"], cf.join(where, "controller"))
        return cls(M, c, _prefilter(d.get("prefilter", "none"), cf.join(where, "prefilter")))

    def controller_class(self, n_u: int, Ts: float) -> ControllerClass:
        c = self.controller
        n_y = len(self.M)
        if c.basis == "velocity":
            return velocity_class(n_u, n_y, c.order, c.structure, Ts)
        return pid_class(n_u, n_y, Ts, c.terms, c.structure)

    def prefilter_tf(self, where: str = "prefilter") -> Tf | None:
        pf = self.prefilter
        if pf == "none":
            return None
        if pf == "one_minus_m":
            if not _is_scalar_identity(self.M):
                raise ConfigError(
                    f"{where}: one_minus_m needs M = m(z) I (equal diagonal, zero off-diagonal)"
                )
            return ONE - self.M[0][0]
        return _tf(pf, where)


@dataclass(frozen=True)
class VrftConfig:
    loop: LoopConfig
    method: str = cf.choice("ls", ("ls", "eiv", "iv"), "Eq. 3.14 | Eqs. 3.26-3.31 | Sec. 3.3.2")
    window: int = cf.count(5, "EIV window l (Eq. 3.26)")
    discard: int = cf.count(0, "initial samples left out of the regression")
    Ts: float | None = cf.number(
        None, "sample time [s]; default: spacing of t", lo=0.0, lo_open=True, optional=True
    )
    outer: LoopConfig | None = None
    eiv_weight: str = cf.choice("identity", ("identity", "residual"), "EIV weighting")

    @classmethod
    def from_dict(cls, d: Any) -> "VrftConfig":
        """The top of the file: its keys, the loop and the optional outer loop."""
        kw = cf.parse_fields(cls, d, "", other_keys=(*_LOOP, "outer"), required=())
        loop = LoopConfig.from_dict({k: d[k] for k in _LOOP if k in d}, "")
        outer = d.get("outer")
        return cls(
            loop, outer=None if outer is None else LoopConfig.from_dict(outer, "outer"), **kw
        )
