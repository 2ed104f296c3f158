"""Read a YAML configuration file; every failure is a ConfigError naming the file.

The strict, line-numbered loader of the versioned model/gains files is
:mod:`lpv_sysid.io.formats`; this one serves the plain configuration files
(config/quadrotor.yaml, identification YAML, node side files).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from lpv_sysid.errors import ConfigError


def read_yaml(path: str | Path, label: str | None = None) -> Any:
    """``yaml.safe_load`` of ``path`` (UTF-8).

    Errors name ``label`` (default: the path): ``"{label}: cannot read ({reason})"`` when
    the file cannot be opened, ``"{label}: malformed YAML ({first line of the parser
    error})"`` when it does not parse. An empty file gives ``None``.
    """
    label = str(path) if label is None else label
    try:
        with open(path, "r", encoding="utf-8") as fh:
            return yaml.safe_load(fh)
    except OSError as exc:
        raise ConfigError(f"{label}: cannot read ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ConfigError(f"{label}: malformed YAML ({first})") from None


__all__ = ["read_yaml"]
