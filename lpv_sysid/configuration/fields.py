"""Configuration mappings checked against declared fields: one declaration per config key.

A configuration dataclass declares each key once, as a field whose metadata says what the
value must be (:func:`number`, :func:`count`, :func:`flag`, :func:`text`, :func:`choice`,
:func:`numbers`, :func:`texts`: type, range, length, allowed values, description).
:func:`parse_fields` checks a YAML mapping against those declarations -- unknown and missing
keys, then every declared value -- and returns the converted values; the class's ``from_dict``
adds only its cross-field rules (``low < high``, one group named by another, ...). Every error
is a :class:`~lpv_sysid.errors.ConfigError` naming the file/section and the field, e.g.
``signals.yaml.groups[1].band: expected 2 values, got 3`` or ``window: expected an integer
>= 0, got -1``.

Why a validator of our own and not a library: the pinned dependency set (setup.py, ROS 2
Jazzy's Python packages) has none (pydantic, attrs/cattrs, marshmallow, jsonschema are not
dependencies and are not to be added for this), the messages must keep the package's wording
(file, section, field path), and the frozen dataclasses stay the configuration objects. The
versioned data files (models, gains) are checked by
:class:`lpv_sysid.io.formats.field_checker.FieldChecker`, which adds matrices and shapes; the
node parameters by :mod:`lpv_sysid.configuration.parameters`, which adds the ROS parameter types.

The predicates :func:`is_finite_number`, :func:`is_count` and the key checks
:func:`check_keys`, :func:`check_config_keys` are used by the configs whose ``from_dict`` is
still written by hand (they keep their own wording).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import MISSING, dataclass
from typing import Any, Collection, Mapping, Optional

from lpv_sysid.errors import ConfigError

#: field kinds (:class:`FieldSpec.kind`)
NUMBER, COUNT, FLAG, TEXT, CHOICE, NUMBERS, TEXTS = (
    "number",
    "count",
    "flag",
    "text",
    "choice",
    "numbers",
    "texts",
)


@dataclass(frozen=True)
class FieldSpec:
    """What the value of one config key must be (the ``"spec"`` metadata of a field).

    ``lo``/``hi``: inclusive bounds (``lo_open``: ``x > lo``); ``NUMBERS`` apply them to every
    entry. ``unit`` is printed after a limit (``" s"``). ``length``: exact number of entries of
    a list. ``optional``: ``None`` (YAML ``null``) is accepted and kept. ``key``: the YAML key
    when it differs from the field name."""

    kind: str
    doc: str = ""
    lo: Optional[float] = None
    hi: Optional[float] = None
    lo_open: bool = False
    unit: str = ""
    length: Optional[int] = None
    choices: tuple = ()
    optional: bool = False
    nonempty: bool = True
    unique: bool = False
    key: str = ""


def _field(default: Any, spec: FieldSpec) -> Any:
    if isinstance(default, (list, dict, set)):
        raise TypeError(f"mutable default {default!r}: use a tuple")
    return dataclasses.field(default=default, metadata={"spec": spec})


def number(default: Any = MISSING, doc: str = "", **kw: Any) -> Any:
    """A finite real number (``bool`` is no number) within ``lo``/``hi`` (``lo_open``)."""
    return _field(default, FieldSpec(NUMBER, doc, **kw))


def count(default: Any = MISSING, doc: str = "", *, lo: int = 0, **kw: Any) -> Any:
    """An integer ``>= lo`` (``bool`` excluded), at most ``hi``: seeds, orders, iterations."""
    return _field(default, FieldSpec(COUNT, doc, lo=lo, **kw))


def flag(default: Any = MISSING, doc: str = "", **kw: Any) -> Any:
    """``true`` or ``false``."""
    return _field(default, FieldSpec(FLAG, doc, **kw))


def text(default: Any = MISSING, doc: str = "", **kw: Any) -> Any:
    """A string (non-empty unless ``nonempty=False``)."""
    return _field(default, FieldSpec(TEXT, doc, **kw))


def choice(default: Any, choices: tuple, doc: str = "", **kw: Any) -> Any:
    """One of ``choices``."""
    return _field(default, FieldSpec(CHOICE, doc, choices=tuple(choices), **kw))


def numbers(default: Any = MISSING, doc: str = "", **kw: Any) -> Any:
    """A list of finite numbers (``length``, bounds per entry) -> tuple of floats."""
    return _field(default, FieldSpec(NUMBERS, doc, **kw))


def texts(default: Any = MISSING, doc: str = "", **kw: Any) -> Any:
    """A list of strings (non-empty list of non-empty strings; ``unique``) -> tuple."""
    return _field(default, FieldSpec(TEXTS, doc, **kw))


def specs(cls: type) -> dict[str, FieldSpec]:
    """Field name -> :class:`FieldSpec` of the declared fields of dataclass ``cls``."""
    return {f.name: f.metadata["spec"] for f in dataclasses.fields(cls) if "spec" in f.metadata}


def _path(where: str, name: str) -> str:
    return f"{where}.{name}" if where else name


def _bad(path: str, msg: str) -> ConfigError:
    return ConfigError(f"{path}: {msg}")


def _limit(x: float, spec: FieldSpec, path: str) -> None:
    if spec.lo is not None:
        if spec.lo_open and not x > spec.lo:
            raise _bad(path, f"must be > {spec.lo:g}, got {x!r}")
        if not spec.lo_open and x < spec.lo:
            raise _bad(path, f"must be >= {spec.lo:g}, got {x!r}")
    if spec.hi is not None and x > spec.hi:
        raise _bad(path, f"{x:g}{spec.unit} exceeds the limit of {spec.hi:g}{spec.unit}")


def _number(v: Any, spec: FieldSpec, path: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _bad(path, f"expected a number, got {v!r}")
    try:
        x = float(v)
    except OverflowError:
        raise _bad(path, f"must be finite, got an integer of {len(str(abs(v)))} digits") from None
    if not math.isfinite(x):
        raise _bad(path, f"must be finite, got {v!r}")
    _limit(x, spec, path)
    return x


def check_value(spec: FieldSpec, v: Any, path: str) -> Any:
    """``v`` checked against ``spec`` and converted (floats, ints, tuples); ConfigError
    ``"{path}: ..."`` otherwise."""
    if v is None and spec.optional:
        return None
    kind = spec.kind
    if kind == NUMBER:
        return _number(v, spec, path)
    if kind == COUNT:
        lo = int(spec.lo or 0)
        if not is_count(v, lo):
            raise _bad(path, f"expected an integer >= {lo}, got {v!r}")
        if spec.hi is not None and v > spec.hi:
            raise _bad(path, f"{v} exceeds the limit of {spec.hi:g}{spec.unit}")
        return int(v)
    if kind == FLAG:
        if not isinstance(v, bool):
            raise _bad(path, f"expected true or false, got {v!r}")
        return v
    if kind == TEXT:
        if not isinstance(v, str) or (spec.nonempty and not v):
            raise _bad(
                path, f"expected a{' non-empty' if spec.nonempty else ''} string, got {v!r}"
            )
        return v
    if kind == CHOICE:
        if v not in spec.choices:
            names = [str(c) for c in spec.choices]
            raise _bad(path, f"{v!r}; use {', '.join(names[:-1])} or {names[-1]}")
        return v
    if kind == NUMBERS:
        if not isinstance(v, (list, tuple)):
            raise _bad(path, f"expected a list, got {v!r}")
        if spec.length is not None and len(v) != spec.length:
            raise _bad(path, f"expected {spec.length} values, got {len(v)}")
        return tuple(_number(x, spec, f"{path}[{i}]") for i, x in enumerate(v))
    if kind == TEXTS:
        if (
            not isinstance(v, (list, tuple))
            or (spec.nonempty and not v)
            or not all(isinstance(c, str) and c for c in v)
        ):
            raise _bad(path, f"expected a non-empty list of names, got {v!r}")
        if spec.unique and len(set(v)) != len(v):
            raise _bad(path, f"duplicate names in {list(v)}")
        return tuple(v)
    raise TypeError(f"unknown field kind {kind!r}")


def parse_fields(
    cls: type,
    d: Any,
    where: str,
    *,
    other_keys: Collection[str] = (),
    required: Optional[Collection[str]] = None,
) -> dict[str, Any]:
    """The declared fields of ``cls`` present in the mapping ``d``, checked and converted
    (field name -> value); ``other_keys``: further keys the caller parses itself.

    Unknown keys, then missing ``required`` keys (default: the declared fields without a
    default), are refused in the wording of :func:`check_keys`; then each value is checked by
    :func:`check_value` with the path ``{where}.{key}``."""
    declared = {f.name: f for f in dataclasses.fields(cls) if "spec" in f.metadata}
    keys = {(f.metadata["spec"].key or name): name for name, f in declared.items()}
    if required is None:
        required = [
            k
            for k, name in keys.items()
            if declared[name].default is MISSING and declared[name].default_factory is MISSING
        ]
    check_keys(d, set(keys) | set(other_keys), where, required=required, list_allowed=True)
    return {
        keys[k]: check_value(declared[keys[k]].metadata["spec"], v, _path(where, k))
        for k, v in d.items()
        if k in keys
    }


def is_finite_number(v: Any) -> bool:
    """``v`` is an ``int`` or ``float`` (not ``bool``: YAML ``true`` is no number), finite."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def is_count(v: Any, minimum: int = 0) -> bool:
    """``v`` is an ``int`` (``bool`` excluded) ``>= minimum``: seeds, orders, lags."""
    return isinstance(v, int) and not isinstance(v, bool) and v >= minimum


def check_keys(
    d: Any,
    allowed: Collection[str],
    where: str,
    *,
    required: Collection[str] = (),
    list_allowed: bool = False,
) -> None:
    """Raise ConfigError unless ``d`` is a mapping whose keys are in ``allowed``.

    Messages (checked in this order): ``"{where}: expected a mapping, got {type}"``,
    ``"{where}: unknown key(s) [...]"`` (followed by ``"; allowed [...]"`` when
    ``list_allowed``), ``"{where}: missing key(s) [...]"`` for absent ``required`` keys.
    """
    if not isinstance(d, Mapping):
        raise ConfigError(f"{where}: expected a mapping, got {type(d).__name__}")
    unknown = sorted(set(d) - set(allowed), key=str)
    if unknown:
        hint = f"; allowed {sorted(allowed)}" if list_allowed else ""
        raise ConfigError(f"{where}: unknown key(s) {unknown}{hint}")
    missing = sorted(set(required) - set(d))
    if missing:
        raise ConfigError(f"{where}: missing key(s) {missing}")


def check_config_keys(d: Any, allowed: Collection[str], what: str) -> None:
    """:func:`check_keys` in the wording of the MAVLink-side configs (``what`` = "link",
    "offboard", ...): ``"{what} config must be a mapping, got {type}"`` and
    ``"unknown {what} config key(s) [...]; known: [...]"``."""
    if not isinstance(d, Mapping):
        raise ConfigError(f"{what} config must be a mapping, got {type(d).__name__}")
    bad = sorted(set(d) - set(allowed))
    if bad:
        raise ConfigError(f"unknown {what} config key(s) {bad}; known: {sorted(allowed)}")
