"""Build description of lpv_sysid: an ament_python package (ROS 2 Jazzy, colcon) that is also
an ordinary pip-installable Python package.

colcon runs ``setup.py install`` with setup.cfg's ``[install]`` script directory, so every
executable lands in ``lib/lpv_sysid`` where ``ros2 run lpv_sysid <name>`` looks; pip builds a
wheel and puts the same console scripts in the environment's ``bin`` (setup.cfg does not
apply there). The shipped default configs live once, in ``lpv_sysid/config`` (package data,
read through importlib.resources: lpv_sysid/configuration/defaults.py); the same files are
installed again into ``share/lpv_sysid/config`` for launch files and ``--params-file``.
"""

import os
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "lpv_sysid"
#: the shipped default configs (package data), relative to the package directory
CONFIG_GLOB = "config/*.yaml"

# Node entry points: `ros2 run lpv_sysid <name>`.
NODES = [
    "excitation_node",
    "lpv_controller_node",
    "mavlink_bridge_node",
    "data_logger_node",
    "sim_vehicle_node",
    "campaign_node",
    "sequencer_node",
]


def tree_data_files(root: str, dest: str) -> list:
    """data_files entries installing every file below ``root`` under ``dest``, keeping the
    sub-directory layout (a rosbag2 directory must stay a directory)."""
    entries = []
    for dirpath, _dirs, files in sorted(os.walk(root)):
        paths = sorted(os.path.join(dirpath, f) for f in files)
        if paths:
            entries.append(
                (os.path.join(dest, os.path.relpath(dirpath, root)).rstrip("/."), paths)
            )
    return entries


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, PACKAGE + ".*"]),  # not bench/, test/
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml", "LICENSE"]),
        ("share/" + PACKAGE + "/launch", glob("launch/*.launch.py")),
        ("share/" + PACKAGE + "/config", sorted(glob(os.path.join(PACKAGE, CONFIG_GLOB)))),
    ]
    + tree_data_files("msg_samples", "share/" + PACKAGE + "/msg_samples"),
    package_data={PACKAGE: ["py.typed", CONFIG_GLOB]},
    python_requires=">=3.10",
    install_requires=["setuptools"],
    zip_safe=False,  # the configs are read as files (lpv_sysid/configuration/defaults.py)
    maintainer="lpv_sysid maintainers",
    maintainer_email="maintainers@example.com",
    description="Safe large-domain system identification of unstable multirotors "
    "with robust LPV control (PX4, MAVLink/MAVROS, rosbag2).",
    license="BSD-3-Clause",
    license_files=["LICENSE"],
    entry_points={
        "console_scripts": [f"{n} = {PACKAGE}.nodes.{n}:main" for n in NODES]
        + [f"lpv-sysid = {PACKAGE}.cli.main:main"],
    },
)
