"""Checks shared by the frozen configuration dataclasses (``from_dict`` / ``__post_init__``).

DESIGN.md: configuration objects validate in ``from_dict`` and name bad keys. The key
check and the "real, finite number" / "count" predicates were written out in every
config class; they live here once. The predicates return ``bool`` so that each caller
keeps its own wording (the section and field it names), the key check raises
:class:`~lpv_sysid.errors.ConfigError` itself with one fixed wording.
"""

from __future__ import annotations

import math
from typing import Any, Collection, Mapping

from lpv_sysid.errors import ConfigError


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
    unknown = sorted(set(d) - set(allowed))
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


__all__ = ["check_config_keys", "check_keys", "is_count", "is_finite_number"]
