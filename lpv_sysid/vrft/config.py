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

_TOP = {
    "reference_model",
    "controller",
    "prefilter",
    "method",
    "window",
    "discard",
    "Ts",
    "outer",
    "eiv_weight",
}
_LOOP = {"reference_model", "controller", "prefilter"}


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


@dataclass(frozen=True)
class LoopConfig:
    M: TfMatrix = field(compare=False)
    controller: dict = field(compare=False)
    prefilter: Any = "none"

    @classmethod
    def from_dict(cls, d: Any, where: str) -> "LoopConfig":
        if not isinstance(d, dict):
            raise ConfigError(f"{where}: expected a mapping")
        for k in ("reference_model", "controller"):
            if k not in d:
                raise ConfigError(f"{where}: missing key {k!r}")
        M = parse_model(d["reference_model"], f"{where}reference_model")
        c = d["controller"]
        if not isinstance(c, dict):
            raise ConfigError(f"{where}controller: expected a mapping")
        bad = set(c) - {"basis", "terms", "order", "structure"}
        if bad:
            raise ConfigError(f"{where}controller: unknown key(s) {sorted(bad)}")
        if c.get("basis", "pid") not in ("pid", "velocity"):
            raise ConfigError(f"{where}controller.basis: {c.get('basis')!r}; use pid or velocity")
        pf = d.get("prefilter", "none")
        if isinstance(pf, dict):
            _tf(pf, f"{where}prefilter")
        elif pf not in ("none", "one_minus_m", None):
            raise ConfigError(f"{where}prefilter: {pf!r}; use none, one_minus_m or {{num, den}}")
        return cls(M, dict(c), pf or "none")

    def controller_class(self, n_u: int, Ts: float) -> ControllerClass:
        c = self.controller
        n_y = len(self.M)
        structure = c.get("structure", "full")
        if c.get("basis", "pid") == "velocity":
            return velocity_class(n_u, n_y, c.get("order", 1), structure, Ts)
        return pid_class(n_u, n_y, Ts, c.get("terms", ["p", "i"]), structure)

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
        if not isinstance(d, dict):
            raise ConfigError("vrft config: expected a YAML mapping at top level")
        bad = set(d) - _TOP
        if bad:
            raise ConfigError(f"vrft config: unknown key(s) {sorted(bad)}; known: {sorted(_TOP)}")
        kw = cf.parse_fields(cls, d, "", other_keys=_LOOP | {"outer"}, required=())
        loop = LoopConfig.from_dict({k: d[k] for k in _LOOP if k in d}, "")
        outer = LoopConfig.from_dict(d["outer"], "outer.") if d.get("outer") is not None else None
        return cls(loop, outer=outer, **kw)
