"""Configuration mappings checked against declared fields: one declaration per config key.

A configuration dataclass declares each key once, as a field whose metadata says what the
value must be (:func:`number`, :func:`count`, :func:`flag`, :func:`text`, :func:`choice`,
:func:`numbers`, :func:`counts`, :func:`texts`, :func:`matrix`, :func:`table`: type, range,
length, allowed values, description with unit). :func:`parse_fields` checks a YAML mapping
against those declarations -- unknown and missing keys, then every declared value -- and
returns the converted values; the class's ``from_dict`` adds only its cross-field rules
(``low < high``, one group named by another, ...) and parses its nested sections by calling
their ``from_dict`` with the path. A class that is also built in code (tests, replay, a
caller's ``dataclasses.replace``) runs the same declared checks on the instance with
:func:`check_fields` (in ``validate``) or :func:`normalize_fields` (in ``__post_init__``,
storing the converted values). Every error is a :class:`~lpv_sysid.errors.ConfigError`
naming the file/section and the field, e.g. ``signals.yaml.groups[1].band: expected 2
values, got 3`` or ``link.link_timeout: 1e+09 s exceeds the limit of 10 s``; unknown keys
are refused naming them (``unknown key(s) [...]; allowed [...]``).

Field kinds beyond the scalars, each small and general:

* :func:`counts` -- a list of integers (channel numbers, state indices, table rows);
* :func:`matrix` -- a list of rows of numbers of a fixed shape (an inertia matrix);
* :func:`table` -- a mapping ``name -> value`` with one declared value kind (stream rates,
  timeouts per stream, PX4 parameters), optionally restricted to known names, stored as a
  dict or as ``(name, value)`` pairs;
* ``choices`` on :func:`texts` (each entry one of them) and :func:`numbers` (a keyword in
  place of the list, e.g. ``rate_bound: design``); ``fold_case`` compares names in upper
  case (PX4 mode names, solver names) and keeps the value as written;
* ``scalar`` on :func:`numbers` and :func:`counts`: a bare number is a list of one
  (``std`` or ``[std, rate_hz]``); ``length`` may list the allowed lengths;
* ``nullable``: YAML ``null`` stands for the default (the key counts as absent);
* ``section``: the key lives in a sub-mapping of the file (``runner: {loop_period: ...}``)
  while the dataclass stays flat.

Why a validator of our own and not a library: the pinned dependency set (setup.py, ROS 2
Jazzy's Python packages) has none (pydantic, attrs/cattrs, marshmallow, jsonschema are not
dependencies and are not to be added for this), the messages must keep the package's wording
(file, section, field path), and the frozen dataclasses stay the configuration objects. The
versioned data files (models, gains) are checked by
:class:`lpv_sysid.io.formats.field_checker.FieldChecker`, which adds matrices and shapes; the
node parameters by :mod:`lpv_sysid.configuration.parameters`, which adds the ROS parameter types.

The predicates :func:`is_finite_number` and :func:`is_count` serve values that are no
configuration field (PX4 parameter values, call arguments); :func:`check_keys` is the key
check of :func:`parse_fields`, also used for mappings that are no dataclass.
"""

from __future__ import annotations

import dataclasses
import math
import numbers as _numbers
from dataclasses import MISSING, dataclass
from typing import Any, Callable, Collection, Mapping, Optional, Union

from lpv_sysid.errors import ConfigError

#: field kinds (:class:`FieldSpec.kind`)
NUMBER, COUNT, FLAG, TEXT, CHOICE, NUMBERS, COUNTS, TEXTS, MATRIX, TABLE = (
    "number",
    "count",
    "flag",
    "text",
    "choice",
    "numbers",
    "counts",
    "texts",
    "matrix",
    "table",
)


@dataclass(frozen=True)
class FieldSpec:
    """What the value of one config key must be (the ``"spec"`` metadata of a field).

    ``lo``/``hi``: inclusive bounds (``lo_open``: ``x > lo``, ``hi_open``: ``x < hi``); the
    list kinds apply them to every entry. ``unit`` is printed after a limit (``" s"``).
    ``length``: the number of entries of a list (an int, or a tuple of allowed numbers);
    ``shape``: (rows, columns) of a :data:`MATRIX`. ``choices``: the allowed values of a
    :data:`CHOICE`, the allowed entries of :data:`TEXTS`, the allowed keys of a
    :data:`TABLE`, the keywords a :data:`NUMBERS` value may be instead of a list;
    ``fold_case``: names compared in upper case, kept as written. ``optional``: ``None``
    (YAML ``null``) is accepted and kept; ``nullable``: ``None`` means the default (the key
    counts as absent). ``nonempty``: a text, a name list or an integer list must not be
    empty; ``unique``: no entry twice. ``scalar``: a :data:`NUMBERS` (:data:`COUNTS`)
    value may be a bare number (integer), a list of one. ``item``: what every value of a
    :data:`TABLE` must be (None: anything, checked by the class); ``pairs``: the table is
    stored as ``(name, value)`` pairs in file order instead of a dict. ``key``: the YAML key
    when it differs from the field name; ``section``: the sub-mapping of the file that holds
    the key."""

    kind: str
    doc: str = ""
    lo: Optional[float] = None
    hi: Optional[float] = None
    lo_open: bool = False
    hi_open: bool = False
    unit: str = ""
    length: Union[int, tuple, None] = None
    shape: tuple = ()
    choices: tuple = ()
    fold_case: bool = False
    optional: bool = False
    nullable: bool = False
    nonempty: bool = True
    unique: bool = False
    scalar: bool = False
    item: Optional["FieldSpec"] = None
    pairs: bool = False
    key: str = ""
    section: str = ""


def _field(default: Any, spec: FieldSpec) -> Any:
    if isinstance(default, dict):  # a table: every instance gets its own copy
        return dataclasses.field(default_factory=lambda: dict(default), metadata={"spec": spec})
    if isinstance(default, (list, set)):
        raise TypeError(f"mutable default {default!r}: use a tuple")
    return dataclasses.field(default=default, metadata={"spec": spec})


def number(default: Any = MISSING, doc: str = "", **kw: Any) -> Any:
    """A finite real number (``bool`` is no number) within ``lo``/``hi`` (``lo_open``,
    ``hi_open``)."""
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
    """One of ``choices`` (``fold_case``: in upper case, kept as written)."""
    return _field(default, FieldSpec(CHOICE, doc, choices=tuple(choices), **kw))


def numbers(default: Any = MISSING, doc: str = "", **kw: Any) -> Any:
    """A list of finite numbers (``length``, bounds per entry) -> tuple of floats; a bare
    number with ``scalar``; one of the keywords ``choices`` instead of a list."""
    return _field(default, FieldSpec(NUMBERS, doc, **kw))


def counts(default: Any = MISSING, doc: str = "", *, lo: int = 0, **kw: Any) -> Any:
    """A non-empty list of integers ``>= lo`` (at most ``hi``; ``length``, ``unique``) ->
    tuple of ints: channel numbers, state indices, table rows."""
    return _field(default, FieldSpec(COUNTS, doc, lo=lo, **kw))


def texts(default: Any = MISSING, doc: str = "", **kw: Any) -> Any:
    """A list of strings (non-empty list of non-empty strings; ``unique``; each one of
    ``choices`` when given) -> tuple."""
    return _field(default, FieldSpec(TEXTS, doc, **kw))


def matrix(default: Any = MISSING, doc: str = "", *, shape: tuple, **kw: Any) -> Any:
    """A list of ``shape[0]`` rows of ``shape[1]`` finite numbers -> tuple of row tuples."""
    return _field(default, FieldSpec(MATRIX, doc, shape=tuple(shape), **kw))


def table(default: Any = MISSING, doc: str = "", *, item: Optional[FieldSpec], **kw: Any) -> Any:
    """A mapping ``name -> value``: names among ``choices`` when given, every value checked
    against ``item`` (None: kept as given, the class checks it) -> dict (a dict default is
    copied per instance), or ``(name, value)`` pairs with ``pairs``."""
    return _field(default, FieldSpec(TABLE, doc, item=item, **kw))


def specs(cls: type) -> dict[str, FieldSpec]:
    """Field name -> :class:`FieldSpec` of the declared fields of dataclass ``cls``."""
    return {f.name: f.metadata["spec"] for f in dataclasses.fields(cls) if "spec" in f.metadata}


def join(where: str, name: str) -> str:
    """The path of key ``name`` under ``where`` (``where.name``; ``name`` at the top)."""
    return f"{where}.{name}" if where else name


def _bad(path: str, msg: str) -> ConfigError:
    return ConfigError(f"{path}: {msg}")


def error(where: str, key: str, msg: str) -> ConfigError:
    """The ConfigError of a rule on key ``key`` under ``where``: ``"{where}.{key}: {msg}"``
    (the wording of the declared checks, for the cross-field rules of a class)."""
    return _bad(join(where, key), msg)


def _limit(x: float, spec: FieldSpec, path: str) -> None:
    if spec.lo is not None:
        if spec.lo_open and not x > spec.lo:
            raise _bad(path, f"must be > {spec.lo:g}, got {x!r}")
        if not spec.lo_open and x < spec.lo:
            raise _bad(path, f"must be >= {spec.lo:g}, got {x!r}")
    if spec.hi is not None:
        if spec.hi_open and not x < spec.hi:
            raise _bad(path, f"{x:g}{spec.unit} must be below {spec.hi:g}{spec.unit}")
        if not spec.hi_open and x > spec.hi:
            raise _bad(path, f"{x:g}{spec.unit} exceeds the limit of {spec.hi:g}{spec.unit}")


def _is_number(v: Any) -> bool:
    """A real number of any numeric type (numpy scalars built in code included), no bool."""
    return isinstance(v, _numbers.Real) and not isinstance(v, bool)


def _number(v: Any, spec: FieldSpec, path: str) -> float:
    if not _is_number(v):
        raise _bad(path, f"expected a number, got {v!r}")
    try:
        x = float(v)
    except OverflowError:
        raise _bad(path, f"must be finite, got an integer of {len(str(abs(v)))} digits") from None
    if not math.isfinite(x):
        raise _bad(path, f"must be finite, got {v!r}")
    _limit(x, spec, path)
    return x


def _count(v: Any, spec: FieldSpec, path: str) -> int:
    lo = int(spec.lo or 0)
    n = int(v) if isinstance(v, _numbers.Integral) and not isinstance(v, bool) else None
    if n is None or n < lo:
        raise _bad(path, f"expected an integer >= {lo}, got {v!r}")
    if spec.hi is not None and n > spec.hi:
        raise _bad(path, f"{n} exceeds the limit of {spec.hi:g}{spec.unit}")
    return n


def _fold(name: Any, spec: FieldSpec) -> Any:
    return name.upper() if spec.fold_case and isinstance(name, str) else name


def _one_of(v: Any, spec: FieldSpec, path: str) -> Any:
    if _fold(v, spec) not in [_fold(c, spec) for c in spec.choices]:
        names = [str(c) for c in spec.choices]
        use = f"{', '.join(names[:-1])} or {names[-1]}" if len(names) > 1 else names[0]
        raise _bad(path, f"{v!r}; use {use}")
    return v


def _sequence(v: Any, spec: FieldSpec, path: str) -> list:
    """The entries of a list value, its length checked (``length``)."""
    if not isinstance(v, (list, tuple)):
        raise _bad(path, f"expected a list, got {v!r}")
    n = spec.length
    allowed = (n,) if isinstance(n, int) else n
    if allowed is not None and len(v) not in allowed:
        want = " or ".join(str(k) for k in allowed)
        raise _bad(path, f"expected {want} values, got {len(v)}")
    return list(v)


def _unique(v: list, spec: FieldSpec, path: str, what: str) -> None:
    folded = [_fold(x, spec) for x in v]
    if spec.unique and len(set(folded)) != len(folded):
        raise _bad(path, f"duplicate {what} in {list(v)}")


def _numbers_value(v: Any, spec: FieldSpec, path: str) -> Any:
    if isinstance(v, str) and spec.choices:
        return _one_of(v, spec, path)
    if spec.scalar and _is_number(v):
        v = [v]
    return tuple(_number(x, spec, f"{path}[{i}]") for i, x in enumerate(_sequence(v, spec, path)))


def _counts_value(v: Any, spec: FieldSpec, path: str) -> tuple:
    if spec.scalar and isinstance(v, int) and not isinstance(v, bool):
        v = [v]
    items = _sequence(v, spec, path)
    if spec.nonempty and not items:
        raise _bad(path, "expected a non-empty list of integers, got []")
    out = [_count(x, spec, f"{path}[{i}]") for i, x in enumerate(items)]
    _unique(out, spec, path, "values")
    return tuple(out)


def _texts_value(v: Any, spec: FieldSpec, path: str) -> tuple:
    if (
        not isinstance(v, (list, tuple))
        or (spec.nonempty and not v)
        or not all(isinstance(c, str) and c for c in v)
    ):
        raise _bad(
            path, f"expected a{' non-empty' if spec.nonempty else ''} list of names, got {v!r}"
        )
    if spec.choices:
        for i, c in enumerate(v):
            _one_of(c, spec, f"{path}[{i}]")
    _unique(list(v), spec, path, "names")
    return tuple(v)


def _matrix_value(v: Any, spec: FieldSpec, path: str) -> tuple:
    rows, cols = spec.shape
    if not isinstance(v, (list, tuple)) or len(v) != rows:
        raise _bad(path, f"expected {rows} rows of {cols} numbers, got {v!r}")
    row = dataclasses.replace(spec, kind=NUMBERS, length=cols)
    return tuple(_numbers_value(r, row, f"{path}[{i}]") for i, r in enumerate(v))


def _table_value(v: Any, spec: FieldSpec, path: str) -> Any:
    if (
        spec.pairs
        and isinstance(v, (list, tuple))
        and all(isinstance(p, (list, tuple)) and len(p) == 2 for p in v)
    ):
        v = dict(v)  # the stored form, (name, value) pairs
    if not isinstance(v, Mapping):
        raise _bad(path, f"expected a mapping name: value, got {v!r}")
    bad = [k for k in v if not (isinstance(k, str) and k)]
    if bad:
        raise _bad(path, f"names must be non-empty strings, got {bad}")
    if spec.choices:
        check_keys(v, spec.choices, path, list_allowed=True)
    out = {
        k: x if spec.item is None else check_value(spec.item, x, join(path, k))
        for k, x in v.items()
    }
    return tuple(out.items()) if spec.pairs else out


def check_value(spec: FieldSpec, v: Any, path: str) -> Any:
    """``v`` checked against ``spec`` and converted (floats, ints, tuples, dicts); ConfigError
    ``"{path}: ..."`` otherwise."""
    if v is None and spec.optional:
        return None
    kind = spec.kind
    if kind == NUMBER:
        return _number(v, spec, path)
    if kind == COUNT:
        return _count(v, spec, path)
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
        return _one_of(v, spec, path)
    if kind == NUMBERS:
        return _numbers_value(v, spec, path)
    if kind == COUNTS:
        return _counts_value(v, spec, path)
    if kind == TEXTS:
        return _texts_value(v, spec, path)
    if kind == MATRIX:
        return _matrix_value(v, spec, path)
    if kind == TABLE:
        return _table_value(v, spec, path)
    raise TypeError(f"unknown field kind {kind!r}")


def _declared(cls: type) -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(cls) if "spec" in f.metadata}


def _yaml_key(f: dataclasses.Field) -> str:
    return f.metadata["spec"].key or f.name


def _has_default(f: dataclasses.Field) -> bool:
    return f.default is not MISSING or f.default_factory is not MISSING


def _sections(d: Mapping[str, Any], names: Collection[str], where: str) -> dict[str, Mapping]:
    """The sub-mappings ``names`` of ``d`` (absent or null: empty)."""
    out: dict[str, Mapping] = {}
    for s in names:
        v = d.get(s)
        if v is not None and not isinstance(v, Mapping):
            raise _bad(join(where, s), f"expected a mapping, got {type(v).__name__}")
        out[s] = v or {}
    return out


def parse_fields(
    cls: type,
    d: Any,
    where: str,
    *,
    other_keys: Collection[str] = (),
    required: Optional[Collection[str]] = None,
) -> dict[str, Any]:
    """The declared fields of ``cls`` present in the mapping ``d``, checked and converted
    (field name -> value); ``other_keys``: further keys the caller parses itself (nested
    sections).

    Unknown keys, then missing ``required`` keys (default: the declared fields without a
    default), are refused in the wording of :func:`check_keys`; then each value is checked by
    :func:`check_value` with the path ``{where}.{key}`` (``{where}.{section}.{key}`` for a
    field of a ``section``). A ``nullable`` field given as null is left out (its default
    applies)."""
    declared = _declared(cls)
    by_section: dict[str, dict[str, str]] = {}
    for name, f in declared.items():
        by_section.setdefault(f.metadata["spec"].section, {})[_yaml_key(f)] = name
    top = by_section.pop("", {})
    if required is None:
        required = [k for k, name in top.items() if not _has_default(declared[name])]
    allowed = set(top) | set(by_section) | set(other_keys)
    check_keys(d, allowed, where, required=required, list_allowed=True)
    out: dict[str, Any] = {}
    sources = [(where, d, top)]
    for s, sub in _sections(d, by_section, where).items():
        check_keys(sub, by_section[s], join(where, s), list_allowed=True)
        sources.append((join(where, s), sub, by_section[s]))
    for path, mapping, keys in sources:
        for k, v in mapping.items():
            if k not in keys:
                continue
            spec = declared[keys[k]].metadata["spec"]
            if v is None and spec.nullable:
                continue
            out[keys[k]] = check_value(spec, v, join(path, k))
    return out


def check_fields(obj: Any, where: str) -> dict[str, Any]:
    """The declared fields of the dataclass instance ``obj`` checked against their
    declarations and converted (field name -> value), for an instance built in code: the
    same rules and messages as :func:`parse_fields` (``{where}.{key}``)."""
    out = {}
    for name, f in _declared(type(obj)).items():
        spec = f.metadata["spec"]
        where_s = join(where, spec.section) if spec.section else where
        out[name] = check_value(spec, getattr(obj, name), join(where_s, _yaml_key(f)))
    return out


def normalize_fields(obj: Any, where: str) -> None:
    """:func:`check_fields`, then the converted values stored on ``obj`` (a frozen
    dataclass in its ``__post_init__``): ints become floats, lists tuples."""
    for name, v in check_fields(obj, where).items():
        object.__setattr__(obj, name, v)


def under(path: str, check: Callable[..., Any], *args: Any) -> Any:
    """``check(*args)`` (a checker with its own wording: a URL, a dialect, a file) with its
    ConfigError prefixed by the field path, ``"{path}: {message}"``."""
    try:
        return check(*args)
    except ConfigError as exc:
        raise _bad(path, str(exc)) from None


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
    ``list_allowed``), ``"{where}: missing key(s) [...]"`` for absent ``required`` keys;
    without the ``"{where}: "`` for ``where = ""`` (the top of a file, whose reader prefixes
    the file name).
    """
    at = f"{where}: " if where else ""
    if not isinstance(d, Mapping):
        raise ConfigError(f"{at}expected a mapping, got {type(d).__name__}")
    unknown = sorted(set(d) - set(allowed), key=str)
    if unknown:
        hint = f"; allowed {sorted(allowed)}" if list_allowed else ""
        raise ConfigError(f"{at}unknown key(s) {unknown}{hint}")
    missing = sorted(set(required) - set(d))
    if missing:
        raise ConfigError(f"{at}missing key(s) {missing}")
