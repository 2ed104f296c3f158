"""ament_python build description for lpv_sysid (ROS 2 Jazzy)."""

import os
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "lpv_sysid"

# Node entry points: `ros2 run lpv_sysid <name>`.
NODES = [
    "excitation_node",
    "lpv_controller_node",
    "mavlink_bridge_node",
    "data_logger_node",
    "sim_vehicle_node",
    "campaign_node",
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
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/launch", glob("launch/*.launch.py")),
        ("share/" + PACKAGE + "/config", glob("config/*.yaml")),
    ]
    + tree_data_files("msg_samples", "share/" + PACKAGE + "/msg_samples"),
    package_data={PACKAGE: ["py.typed"]},
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="lpv_sysid maintainers",
    maintainer_email="maintainers@example.com",
    description="Safe large-domain system identification of unstable multirotors "
    "with robust LPV control (PX4, MAVLink/MAVROS, rosbag2).",
    license="BSD-3-Clause",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [f"{n} = {PACKAGE}.nodes.{n}:main" for n in NODES]
        + [f"lpv-sysid = {PACKAGE}.cli.main:main"],
    },
)
