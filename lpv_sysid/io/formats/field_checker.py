"""Field-path checks of the versioned files: every error is ``ConfigError("<file>: <path>: ...")``.

:class:`FieldChecker` checks one value of a parsed YAML document (a mapping's keys, a finite
number, an integer, a string, a vector of n numbers, an n x m matrix) and names the file and the
field path in its message, e.g. ``gains.yaml: vertices[3].K: expected shape 4x12, got 4x11``.
The format modules of :mod:`lpv_sysid.io.formats` are written with it.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, NoReturn, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError


class FieldChecker:
    """Field-path aware validators: every error is ``ConfigError("<label>: <path>: ...")``."""

    def __init__(self, label: str):
        self.label = label

    def fail(self, path: str, msg: str) -> NoReturn:
        raise ConfigError(f"{self.label}: {path}: {msg}" if path else f"{self.label}: {msg}")

    def mapping(
        self,
        d,
        path: str,
        required: Sequence[str],
        optional: Sequence[str] = (),
        extra_ok: bool = False,
    ) -> Mapping:
        if not isinstance(d, Mapping):
            self.fail(path, f"expected a mapping, got {kind_of(d)}")
        bad = [k for k in d if not isinstance(k, str)]
        if bad:
            self.fail(path, f"keys must be strings, got {bad}")
        missing = [k for k in required if k not in d]
        if missing:
            self.fail(path, f"missing key(s) {missing}")
        if not extra_ok:
            unknown = [k for k in d if k not in required and k not in optional]
            if unknown:
                self.fail(
                    path, f"unknown key(s) {unknown}; allowed: {list(required) + list(optional)}"
                )
        return d

    def number(self, v, path: str, bounded: bool = True) -> float:
        """A finite number; with ``bounded`` (all fields but fit metrics) also
        ``|x| <= MAX_MAGNITUDE`` (io.yaml_file: larger entries overflow downstream products)."""
        from lpv_sysid.io.files import MAX_MAGNITUDE

        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(path, f"expected a number, got {kind_of(v)} {v!r}")
        try:
            x = float(v)
        except OverflowError:
            self.fail(
                path, f"out of range for a double, got an integer of {len(str(abs(v)))} digits"
            )
        if not math.isfinite(x):
            self.fail(path, f"must be finite, got {x}")
        if bounded and abs(x) > MAX_MAGNITUDE:
            self.fail(path, f"magnitude must be <= {MAX_MAGNITUDE:g}, got {x:g}")
        return x

    def integer(self, v, path: str) -> int:
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(path, f"expected an integer, got {kind_of(v)} {v!r}")
        return int(v)

    def string(self, v, path: str, nonempty: bool = True) -> str:
        if not isinstance(v, str) or (nonempty and not v):
            self.fail(
                path,
                f"expected a{' non-empty' if nonempty else ''} string, got {kind_of(v)} {v!r}",
            )
        return v

    def vector(self, v, n: Optional[int], path: str) -> np.ndarray:
        if not isinstance(v, (list, tuple, np.ndarray)):
            self.fail(
                path, f"expected a list of {n if n is not None else ''} numbers, got {kind_of(v)}"
            )
        vals = [self.number(x, f"{path}[{i}]") for i, x in enumerate(v)]
        if n is not None and len(vals) != n:
            self.fail(path, f"expected {n} values, got {len(vals)}")
        return np.array(vals, dtype=float)

    def matrix(self, v, shape: tuple, path: str) -> np.ndarray:
        rows, cols = shape
        if not isinstance(v, (list, tuple, np.ndarray)) or any(
            not isinstance(r, (list, tuple, np.ndarray)) for r in v
        ):
            self.fail(path, f"expected a {rows}x{cols} matrix as a list of rows, got {kind_of(v)}")
        lens = sorted({len(r) for r in v})
        if len(v) != rows or lens != [cols]:
            got = f"{len(v)}x{lens[0]}" if len(lens) == 1 else f"{len(v)} rows of lengths {lens}"
            self.fail(path, f"expected shape {rows}x{cols}, got {got}")
        return np.array(
            [
                [self.number(x, f"{path}[{i}][{j}]") for j, x in enumerate(r)]
                for i, r in enumerate(v)
            ],
            dtype=float,
        ).reshape(rows, cols)


def kind_of(v: Any) -> str:
    """YAML-level name of the type of ``v`` (mapping, list, string, null, boolean, ...)."""
    return {dict: "mapping", list: "list", str: "string", type(None): "null", bool: "boolean"}.get(
        type(v), type(v).__name__
    )


def floats(a: Any) -> list:
    """``a`` as a flat list of Python floats (what the files store)."""
    return [float(x) for x in np.asarray(a, dtype=float).ravel()]


def rows(a: Any) -> list:
    """A matrix as a list of rows of Python floats (what the files store)."""
    return [[float(x) for x in row] for row in np.asarray(a, dtype=float)]
