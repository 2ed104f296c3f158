"""Where the shipped configuration files are: the source tree or the ament share dir."""

from __future__ import annotations

from pathlib import Path

from lpv_sysid.errors import ConfigError


def config_dir() -> Path:
    """``config/`` next to the package in a source checkout, else ``share/lpv_sysid/config``
    of an installed ROS 2 package (colcon), else a ConfigError saying where it looked."""
    here = Path(__file__).resolve().parents[2] / "config"
    if here.is_dir():
        return here
    try:  # installed with colcon: ament index knows the share directory
        from ament_index_python.packages import get_package_share_directory

        share = Path(get_package_share_directory("lpv_sysid")) / "config"
        if share.is_dir():
            return share
    except (ImportError, LookupError):
        pass
    raise ConfigError(
        f"cannot find the lpv_sysid config directory (looked in {here} and the ament share)"
    )


def config_file(name: str) -> Path:
    path = config_dir() / name
    if not path.is_file():
        raise ConfigError(f"shipped config file {name!r} is missing from {path.parent}")
    return path
