"""The ament_python package installs the way colcon installs it (setup.py install with the
setup.cfg script dir): share/ files, the ament resource index, and every node executable
under lib/lpv_sysid so `ros2 run lpv_sysid <node>` finds it."""

import ast
import importlib
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NODES = [
    "excitation_node",
    "lpv_controller_node",
    "mavlink_bridge_node",
    "data_logger_node",
    "sim_vehicle_node",
]


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    work = tmp_path_factory.mktemp("pkg")
    root = work / "root"
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    proc = subprocess.run(
        [
            sys.executable,
            "setup.py",
            "-q",
            "build",
            "--build-base",
            str(work / "build"),
            "install",
            "--root",
            str(root),
            "--prefix",
            "/opt/ros_ws",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    for leftover in ("lpv_sysid.egg-info",):
        # setup.py writes egg-info into the source tree; keep the checkout clean
        p = ROOT / leftover
        if p.exists():
            import shutil

            shutil.rmtree(p)
    return root / "opt" / "ros_ws"


def test_share_files_and_resource_index(installed):
    share = installed / "share" / "lpv_sysid"
    assert (
        installed / "share" / "ament_index" / "resource_index" / "packages" / "lpv_sysid"
    ).is_file()
    assert (share / "package.xml").is_file()
    for launch in ("phase1.launch.py", "phase2.launch.py", "sim.launch.py"):
        assert (share / "launch" / launch).is_file()
    for cfg in ("quadrotor.yaml", "synthesis.yaml", "signals_phase2.yaml", "lpv_controller.yaml"):
        assert (share / "config" / cfg).is_file()
    # a sample rosbag2 keeps its directory layout (metadata.yaml next to the storage file)
    bag = share / "msg_samples" / "phase2_sim" / "bag_0000"
    assert (bag / "metadata.yaml").is_file() and list(bag.glob("*.mcap"))


def test_every_node_and_the_cli_are_executables_in_lib(installed):
    lib = installed / "lib" / "lpv_sysid"
    for name in NODES + ["lpv-sysid"]:
        assert (lib / name).is_file(), name


@pytest.mark.parametrize("node", NODES)
def test_node_entry_point_is_a_main_function(node):
    tree = ast.parse((ROOT / "lpv_sysid" / "nodes" / f"{node}.py").read_text())
    assert any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in tree.body)


#: import name -> rosdep key, for the third-party modules the package imports
ROSDEP_KEYS = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "yaml": "python3-yaml",
    "matplotlib": "python3-matplotlib",
    "serial": "python3-serial",
}
#: imported, but with no Ubuntu 24.04 package / rosdep key: pip, from requirements-ros.txt
PIP_ONLY = {"pymavlink", "rosbags", "cvxpy", "mavsdk", "scs", "clarabel"}


def _third_party_imports():
    import sys

    mods = set()
    files = [*(ROOT / "lpv_sysid").rglob("*.py"), *(ROOT / "launch").glob("*.py")]
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                mods |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                mods.add(node.module.split(".")[0])
        # message types looked up by name ("std_msgs/msg/Header") through a MsgFactory
        text = path.read_text()
        mods |= {
            p
            for p in (
                "std_msgs",
                "geometry_msgs",
                "sensor_msgs",
                "nav_msgs",
                "diagnostic_msgs",
                "std_srvs",
                "builtin_interfaces",
            )
            if f"{p}/msg/" in text or f"{p}/srv/" in text
        }
    return {m for m in mods if m not in sys.stdlib_module_names and m != "lpv_sysid"}


def test_package_xml_declares_exactly_what_the_code_imports():
    xml = ET.parse(ROOT / "package.xml").getroot()
    assert xml.get("format") == "3" and xml.findtext("name") == "lpv_sysid"
    deps = {e.text for e in xml.findall("exec_depend")}
    used = _third_party_imports() | {"serial"}  # pymavlink's serial links need pyserial
    expected = {ROSDEP_KEYS.get(m, m) for m in used - PIP_ONLY}
    assert deps == expected, (sorted(deps - expected), sorted(expected - deps))
    pip = (ROOT / "requirements-ros.txt").read_text().lower()
    for m in used & PIP_ONLY - {"scs", "clarabel"}:
        assert f"{m}==" in pip, m
    assert xml.find("export/build_type").text == "ament_python"


def test_library_code_never_imports_rclpy_outside_the_shells():
    offenders = []
    for path in (ROOT / "lpv_sysid").rglob("*.py"):
        if "nodes" in path.relative_to(ROOT / "lpv_sysid").parts[:1]:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            if any(n == "rclpy" or n.startswith("rclpy.") for n in names):
                offenders.append(str(path.relative_to(ROOT)))
    assert offenders == []


def test_cli_module_imports():
    assert callable(importlib.import_module("lpv_sysid.cli.main").main)
