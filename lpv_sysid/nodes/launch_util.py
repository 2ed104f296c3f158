"""Launch-file helpers shared by ``launch/*.launch.py``.

The launch files are installed on their own under ``share/lpv_sysid/launch``, so what they
share lives in the package and they import it from here: the launch arguments every
experiment uses (one description each) and the parameter-file lookup in ``config_dir``,
whose default is the ROS share copy of the shipped configs
(:func:`lpv_sysid.default_configs.share_config_dir`). Needs ROS 2 ``launch`` and
``ament_index_python`` (imported only by the launch files).
"""

from __future__ import annotations

from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution

from lpv_sysid.default_configs import PACKAGE, share_config_dir

#: launch argument -> description (shared by every launch file that declares it)
DESCRIPTIONS = {
    "config_dir": "directory holding the node parameter files",
    "signals_file": "signals.npz written by `lpv-sysid signals`",
    "gains_file": "gains.yaml from `lpv-sysid synthesize`",
    "vertex": "vertex body velocity (u, v, w) FRD, m/s, for this run",
    "log_dir": "experiment directory of the data logger",
}

#: marks an argument without default (``ros2 launch`` refuses to start without it)
REQUIRED = None


def declare_arguments(notes: dict[str, str] | None = None, **defaults) -> list:
    """``DeclareLaunchArgument`` for ``config_dir`` and then for each keyword, in order.

    ``config_dir`` defaults to the installed ``share/lpv_sysid/config``. A keyword's value
    is the argument's default (:data:`REQUIRED`: none); its description is the shared one
    of :data:`DESCRIPTIONS`, followed by ``" (<note>)"`` for the names in ``notes``.
    """
    unknown = sorted((set(defaults) | set(notes or {})) - set(DESCRIPTIONS))
    if unknown:
        raise KeyError(f"launch arguments without a description: {unknown}")
    notes = notes or {}
    out = []
    for name, default in {"config_dir": share_config_dir(), **defaults}.items():
        description = DESCRIPTIONS[name] + (f" ({notes[name]})" if name in notes else "")
        if default is REQUIRED:
            out.append(DeclareLaunchArgument(name, description=description))
        else:
            out.append(DeclareLaunchArgument(name, default_value=default, description=description))
    return out


def params(name: str) -> PathJoinSubstitution:
    """The node parameter file ``name`` in the directory of the ``config_dir`` argument."""
    return PathJoinSubstitution([LaunchConfiguration("config_dir"), name])


__all__ = [
    "DESCRIPTIONS",
    "PACKAGE",
    "REQUIRED",
    "declare_arguments",
    "params",
    "share_config_dir",
]
