"""Read a YAML file strictly; every failure is a ConfigError naming the file.

The one YAML reader and writer of the package: the plain configuration files
(config/*.yaml, identification YAML, node side files) come through :func:`read_yaml`, the
versioned model/gains files of :mod:`lpv_sysid.io.formats` through :func:`read_located`
(same loader, every parse error with its line and column), rosbag2 metadata through
:func:`strict_load`; every YAML file the package writes goes through :func:`save_yaml`
(atomic: temporary file + rename). Files are opened by :mod:`lpv_sysid.io.files.opening`
(regular files only, never blocks on a FIFO, size cap :data:`MAX_YAML_BYTES`, UTF-8 only).

The loader and what it checks beyond PyYAML (duplicate keys, nesting, aliases, integer
range, finite floats): :mod:`lpv_sysid.io.files.yaml_loader`.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Optional

import yaml

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.files.opening import MAX_YAML_BYTES, decode_text, read_bytes, read_text
from lpv_sysid.io.files.yaml_loader import NonFiniteError, describe_yaml_error, strict_load


def read_yaml(
    path: str | Path,
    label: Optional[str] = None,
    max_bytes: int = MAX_YAML_BYTES,
    *,
    finite: bool = True,
) -> Any:
    """The strictly loaded YAML document of ``path`` (UTF-8, regular file <= ``max_bytes``).

    Errors name ``label`` (default: the path): ``"{label}: cannot read ({reason})"`` when
    the file cannot be opened (missing, directory, FIFO/device, permission, symlink loop),
    ``"{label}: file too large (...)"``, ``"{label}: not UTF-8 text (...)"``,
    ``"{label}: malformed YAML ({first line of the parser error})"`` when it does not parse
    or breaks a rule of :class:`StrictLoader` (with line and column). With ``finite`` (the
    default, for configuration files) ``"{label}: line L, column C: {key path}: .nan is not a
    finite number ..."``; readers of the package's own outputs (which may record ``.nan``)
    pass ``finite=False``. An empty file gives ``None``.
    """
    label = str(path) if label is None else label
    data = read_bytes(path, label, max_bytes)
    where = label if str(path) in label else f"{label} ({path})"  # content errors name the file
    text = decode_text(data, where)
    try:
        return strict_load(text, finite=finite)
    except NonFiniteError as exc:
        raise ConfigError(f"{where}: {describe_yaml_error(exc)}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{where}: malformed YAML ({describe_yaml_error(exc)})") from None
    except RecursionError:  # defensive: MAX_DEPTH keeps the composer far from the limit
        raise ConfigError(f"{where}: malformed YAML (nesting too deep)") from None


def read_yaml_mapping(
    path: str | Path,
    label: Optional[str] = None,
    *,
    allow_empty: bool = False,
    finite: bool = True,
) -> dict:
    """:func:`read_yaml` of a file whose top level must be a mapping.

    ``"{label}: empty file"`` (``{}`` with ``allow_empty``), ``"{label}: expected a mapping
    at the top level, got a list"``, ``"{label}: top-level keys must be strings, got [None]"``.
    """
    label = str(path) if label is None else label
    d = read_yaml(path, label, finite=finite)
    where = label if str(path) in label else f"{label} ({path})"
    if d is None:
        if allow_empty:
            return {}
        raise ConfigError(f"{where}: empty file (expected a mapping at the top level)")
    if not isinstance(d, dict):
        raise ConfigError(f"{where}: expected a mapping at the top level, got {_kind(d)}")
    bad = [k for k in d if not isinstance(k, str)]
    if bad:
        raise ConfigError(f"{where}: top-level keys must be strings, got {bad[:5]}")
    return d


def read_located(path: str | Path, label: Optional[str] = None) -> Any:
    """:func:`strict_load` of the file ``path`` (not ``finite``: the versioned files check
    each field themselves) with the wording of the versioned files: ``"{label}: malformed YAML
    at line L, column C: {problem}"`` (``label`` defaults to the file name)."""
    path = Path(path)
    label = label or path.name
    return parse_located(read_text(path, label, show_path=True), label)


def parse_located(text: str, label: str) -> Any:
    """:func:`strict_load` of ``text``; a parse error is ``ConfigError`` with line and column."""
    try:
        return strict_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = (
            getattr(exc, "problem", None) or (str(exc).splitlines() or [type(exc).__name__])[0]
        )
        raise ConfigError(f"{label}: malformed YAML{where}: {problem}") from None


class _Dumper(yaml.SafeDumper):
    """Block style for mappings, flow style for vectors and matrix rows."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(not isinstance(v, (list, dict)) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def dump_yaml(doc: Any) -> str:
    """The YAML text :func:`save_yaml` writes: keys in insertion order, mappings in block
    style, lists of scalars (vectors, matrix rows) in flow style."""
    return yaml.dump(
        doc,
        Dumper=_Dumper,
        sort_keys=False,
        default_flow_style=False,
        width=100,
        allow_unicode=True,
    )


def save_yaml(doc: Any, path: str | Path, label: Optional[str] = None) -> None:
    """Write ``doc`` to ``path`` atomically (temporary file in the same directory + rename), so
    a failure never leaves half a file; parent directories are created. An existing
    non-regular ``path`` (FIFO, device) is refused; errors are ``ConfigError("{label}: cannot
    write {path}: ...")`` (``label`` defaults to the file name)."""
    from lpv_sysid.io.files.opening import check_output

    path = Path(path)
    label = label or path.name
    text = dump_yaml(doc)
    check_output(path, label)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
    except OSError as exc:
        raise ConfigError(f"{label}: cannot write {path}: {exc.strerror or exc}") from None


def _kind(v: Any) -> str:
    return {
        list: "a list",
        str: "a string",
        bool: "a boolean",
        int: "a number",
        float: "a number",
    }.get(type(v), type(v).__name__)
