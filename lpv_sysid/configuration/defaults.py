"""Where the shipped default configuration files are: the one lookup of the package.

The defaults (``lpv_sysid/config/*.yaml``; ``config/`` in the repository is a symlink to that
directory) are package data, found through :mod:`importlib.resources`, so the command finds
them from any working directory however the package was installed: a source checkout or
``pip install -e .`` (the working tree), ``pip install .`` (inside the wheel) and colcon (the
package under ``lib/python3.x/site-packages``). setup.py installs the same files a second
time into the ROS share directory, ``share/lpv_sysid/config``, where launch files and
``--params-file`` look (:func:`share_config_dir`).
"""

from __future__ import annotations

import logging
import os
from importlib.resources import files
from pathlib import Path

from lpv_sysid.errors import ConfigError

PACKAGE = "lpv_sysid"
#: the package-data directory of the defaults, and their directory under share/<package>/
SUBDIR = "config"

log = logging.getLogger(__name__)


def config_dir() -> Path:
    """The directory of the shipped defaults inside the installed package."""
    resource = files(PACKAGE).joinpath(SUBDIR)
    if not isinstance(resource, Path):  # zipimport: the callers pass paths to readers
        raise ConfigError(
            f"{PACKAGE} is imported from an archive ({resource}): its config files must be "
            "files on disk; install the package unpacked (pip install .)"
        )
    if not resource.is_dir():
        raise ConfigError(f"the {PACKAGE} installation has no config directory ({resource})")
    return resource


def config_file(name: str) -> Path:
    """The shipped default ``name`` (e.g. ``"synthesis.yaml"``): a file name of
    :func:`config_names`, nothing else (``../../etc/passwd`` or an absolute path is no
    shipped default)."""
    if name not in config_names():
        raise ConfigError(
            f"{name!r} is not a shipped config file; the shipped ones: {', '.join(config_names())}"
        )
    path = config_dir() / name
    if not path.is_file():
        raise ConfigError(f"shipped config file {name!r} is missing from {path.parent}")
    log.debug("shipped default %s", path)
    return path


def config_names() -> list[str]:
    """File names of every shipped default, sorted."""
    return sorted(p.name for p in config_dir().glob("*.yaml"))


def share_config_dir() -> str:
    """``share/lpv_sysid/config`` of the installed ROS 2 package (ament index): the copy of the
    defaults that launch files and ``ros2 run ... --params-file`` use. Needs
    ``ament_index_python`` (a sourced ROS 2)."""
    from ament_index_python.packages import get_package_share_directory

    return os.path.join(get_package_share_directory(PACKAGE), SUBDIR)
