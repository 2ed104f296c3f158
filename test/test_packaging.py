"""The package installs both ways it is meant to.

colcon (``setup.py install`` with setup.cfg's script dir): share/ files, the ament resource
index, and every executable under lib/lpv_sysid so ``ros2 run lpv_sysid <name>`` finds it;
with a real ROS 2 (test/support/ros_real.py) the colcon build itself. pip (the README's
set-up: an editable install into .venv; and ``pip install .``): a wheel with every shipped
config inside the package, installed into a scratch venv whose ``lpv-sysid`` is in ``bin``
and finds its configs from any working directory. Nothing is downloaded: the wheels are built
without build isolation by the test interpreter's setuptools (requirements.txt), and the
scratch venvs see that interpreter's site-packages for numpy & co.
"""

import ast
import importlib
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the one copy of the shipped defaults (config/ in the checkout links here)
PACKAGE_CONFIG = ROOT / "lpv_sysid" / "config"
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
    assert (share / "package.xml").is_file() and (share / "LICENSE").is_file()
    for launch in ("phase1.launch.py", "phase2.launch.py", "sim.launch.py"):
        assert (share / "launch" / launch).is_file()
    # the same files as the package data, byte for byte: one copy in the repository
    shipped = sorted(p.name for p in PACKAGE_CONFIG.glob("*.yaml"))
    assert {"quadrotor.yaml", "synthesis.yaml", "lpv_controller.yaml"} <= set(shipped)
    assert sorted(p.name for p in (share / "config").iterdir()) == shipped
    for name in shipped:
        assert (share / "config" / name).read_bytes() == (PACKAGE_CONFIG / name).read_bytes()
    # a sample rosbag2 keeps its directory layout (metadata.yaml next to the storage file)
    bag = share / "msg_samples" / "phase2_sim" / "bag_0000"
    assert (bag / "metadata.yaml").is_file() and list(bag.glob("*.mcap"))


def test_every_node_and_the_cli_are_executables_in_lib(installed):
    lib = installed / "lib" / "lpv_sysid"
    for name in NODES + ["lpv-sysid"]:
        assert (lib / name).is_file(), name
    assert not (installed / "bin").exists()  # colcon layout: nothing on PATH, ros2 run finds it


def test_colcon_install_ships_the_configs_inside_the_package_too(installed):
    """The installed package finds its defaults without the share directory (pip, or a
    colcon install used outside ROS): the package data is the same files."""
    pkgs = list(installed.glob("lib/python3*/site-packages/lpv_sysid/config"))
    assert len(pkgs) == 1, pkgs
    names = sorted(p.name for p in PACKAGE_CONFIG.glob("*.yaml"))
    assert sorted(p.name for p in pkgs[0].glob("*.yaml")) == names
    assert not list(installed.glob("lib/python3*/site-packages/bench"))  # repo tooling stays out


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
PIP_ONLY = {
    "pymavlink",
    "rosbags",
    "pyulog",
    "control",
    "cvxpy",
    "mavsdk",
    "scs",
    "clarabel",
    "threadpoolctl",
}
#: imported only when the user installed them (``--backend dask``), never required
OPTIONAL = {"dask", "distributed"}


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
    used = (_third_party_imports() - OPTIONAL) | {"serial"}  # pyserial: pymavlink's serial
    expected = {ROSDEP_KEYS.get(m, m) for m in used - PIP_ONLY}
    assert deps == expected, (sorted(deps - expected), sorted(expected - deps))
    pip = (ROOT / "requirements-ros.txt").read_text().lower()
    for m in used & PIP_ONLY - {"scs", "clarabel"}:
        assert f"{m}==" in pip, m
    assert xml.find("export/build_type").text == "ament_python"


def test_license_file_matches_package_xml_and_setup_py():
    """One licence: LICENSE holds the BSD-3-Clause text with package.xml's maintainer, and
    package.xml and setup.py name the same SPDX identifier; colcon installs the file."""
    xml = ET.parse(ROOT / "package.xml").getroot()
    assert xml.findtext("license") == "BSD-3-Clause"
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("BSD 3-Clause License")
    assert "Neither the name of the copyright holder nor the names of its" in text
    maintainer = xml.find("maintainer")
    assert f"{maintainer.text} <{maintainer.get('email')}>" in text
    setup_py = (ROOT / "setup.py").read_text()
    assert 'license="BSD-3-Clause"' in setup_py and '"LICENSE"]' in setup_py


def test_every_declared_test_dependency_is_used_by_a_test():
    """package.xml declares no linter (ament_copyright, ament_flake8, ...) that no test runs:
    each test_depend other than pytest is imported by a test file."""
    xml = ET.parse(ROOT / "package.xml").getroot()
    declared = {e.text for e in xml.findall("test_depend")}
    tests = "\n".join(p.read_text() for p in (ROOT / "test").glob("test_*.py"))
    unused = sorted(
        d
        for d in declared - {"python3-pytest"}
        if not re.search(rf"^\s*(import|from) {d}\b", tests, re.M)
    )
    assert not unused, f"declared in package.xml but run by no test: {unused}"


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


# ---------------------------------------------------------------- pip: wheel, scratch venvs
#: not copied into the build tree (a build writes build/ next to setup.py: the checkout
#: stays clean); bench/ and test/ are copied so that leaving them out is the build's doing
_COPY_IGNORE = shutil.ignore_patterns(
    ".venv",
    ".git",
    ".mypy_cache",
    ".ruff_cache",
    ".pytest_cache",
    "__pycache__",
    "*.egg-info",
    "build",
    "install",
    "log",
    "demo_out",
)
SHIPPED = sorted(p.name for p in PACKAGE_CONFIG.glob("*.yaml"))


def _offline_build_problem() -> str:
    """'' when the test interpreter's setuptools builds wheels and PEP 660 editable wheels
    without a download (>= 70.1 has bdist_wheel built in), else why not."""
    try:
        import setuptools
    except ImportError:
        return "setuptools not installed (requirements.txt pins it)"
    version = tuple(int(x) for x in setuptools.__version__.split(".")[:2])
    if version < (70, 1) and importlib.util.find_spec("wheel") is None:
        return f"setuptools {setuptools.__version__} builds no wheel offline (requirements.txt)"
    return ""


def _run(cmd: list, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    """``cmd`` without the caller's PYTHONPATH: an install is judged on its own (a sourced
    ROS 2 workspace, or a checkout on PYTHONPATH, would otherwise supply lpv_sysid)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run(
        [str(c) for c in cmd], cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env
    )


def _site_packages(python: Path | str) -> list[Path]:
    code = "import sysconfig as s; print(s.get_path('purelib')); print(s.get_path('platlib'))"
    out = _run([python, "-c", code], cwd=ROOT, timeout=60).stdout.split()
    return list(dict.fromkeys(Path(p) for p in out))


def _scratch_venv(path: Path, wheel: Path) -> Path:
    """A venv at ``path`` (no pip of its own) with ``wheel`` installed by the test
    interpreter's pip, offline; then the test interpreter's site-packages are appended to its
    path (numpy, yaml, ...: installed, not downloaded). Returns its ``bin``."""
    r = _run([sys.executable, "-m", "venv", "--without-pip", path], cwd=path.parent, timeout=120)
    assert r.returncode == 0, r.stderr
    py = path / "bin" / "python"
    r = _run(
        [sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "--no-index", wheel],
        cwd=path.parent,
    )
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    own = _site_packages(py)[0]
    (own / "_test_interpreter_site.pth").write_text(
        "".join(f"{p}\n" for p in _site_packages(sys.executable))
    )
    return path / "bin"


@pytest.fixture(scope="module")
def source_copy(tmp_path_factory):
    problem = _offline_build_problem()
    if problem:
        pytest.skip(problem)
    src = tmp_path_factory.mktemp("src") / "lpv_sysid"
    shutil.copytree(ROOT, src, symlinks=True, ignore=_COPY_IGNORE)
    return src


@pytest.fixture(scope="module")
def wheel(source_copy, tmp_path_factory):
    dist = tmp_path_factory.mktemp("dist")
    r = _run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index"]
        + ["-w", dist, source_copy],
        cwd=source_copy,
    )
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    (whl,) = dist.glob("lpv_sysid-*.whl")
    return whl


@pytest.fixture(scope="module")
def pip_installed(wheel, tmp_path_factory):
    return _scratch_venv(tmp_path_factory.mktemp("venv") / "v", wheel)


@pytest.fixture(scope="module")
def editable_installed(source_copy, tmp_path_factory):
    """The Makefile's install (pip install --no-build-isolation --editable .): setuptools'
    PEP 660 hook builds the editable wheel, pip installs it."""
    dist = tmp_path_factory.mktemp("editable")
    code = "import sys; from setuptools import build_meta; build_meta.build_editable(sys.argv[1])"
    r = _run([sys.executable, "-c", code, dist], cwd=source_copy)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    (whl,) = dist.glob("lpv_sysid-*.whl")
    return _scratch_venv(tmp_path_factory.mktemp("venv_editable") / "v", whl)


def test_the_checkout_config_dir_is_the_package_data():
    """config/ (README and docs paths) is the package's own directory, not a second copy."""
    from lpv_sysid.configuration.defaults import config_dir, config_names

    assert (ROOT / "config").resolve() == PACKAGE_CONFIG.resolve() == config_dir().resolve()
    assert config_names() == SHIPPED and len(SHIPPED) >= 15


def test_wheel_holds_only_the_package_with_every_shipped_config(wheel):
    stem = "-".join(wheel.name.split("-")[:2])  # lpv_sysid-0.1.0
    share = f"{stem}.data/data/share/lpv_sysid/config/"
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        assert {n.split("/")[0] for n in names} == {
            "lpv_sysid",
            f"{stem}.dist-info",
            f"{stem}.data",
        }  # no bench/ or test/ package in site-packages
        inside = sorted(n.rsplit("/", 1)[1] for n in names if n.startswith("lpv_sysid/config/"))
        assert inside == SHIPPED
        assert sorted(n[len(share) :] for n in names if n.startswith(share)) == SHIPPED
        for name in SHIPPED:
            data = (PACKAGE_CONFIG / name).read_bytes()
            assert z.read(f"lpv_sysid/config/{name}") == data == z.read(share + name)
        assert "lpv_sysid/py.typed" in names
        entry_points = z.read(f"{stem}.dist-info/entry_points.txt").decode()
    assert "lpv-sysid = lpv_sysid.cli.main:main" in entry_points


def test_pip_install_puts_the_command_in_the_venv_bin_and_finds_the_configs(
    pip_installed, tmp_path
):
    """pip ignores setup.cfg's colcon script directory; the installed command runs from any
    working directory and reads the defaults from the installed package, not the checkout."""
    venv = pip_installed.parent
    cli = pip_installed / "lpv-sysid"
    assert cli.is_file() and not (venv / "lib" / "lpv_sysid").exists()
    assert all((pip_installed / n).is_file() for n in NODES)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    r = _run([cli, "--help"], cwd=elsewhere, timeout=120)
    assert r.returncode == 0 and "usage: lpv-sysid" in r.stdout, r.stderr
    assert "synthesize" in r.stdout and "config" in r.stdout
    site_config = _site_packages(pip_installed / "python")[0] / "lpv_sysid" / "config"
    r = _run([cli, "config"], cwd=elsewhere, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == [str(site_config / n) for n in SHIPPED]
    # a default-config consumer (demo's plan) resolves to the installed files as well
    code = (
        "from pathlib import Path; from lpv_sysid.cli.demo import plan; "
        "print(plan(Path('o'), False, 1.0)[0][1][3])"
    )
    r = _run([pip_installed / "python", "-c", code], cwd=elsewhere, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == str(site_config / "quadrotor.yaml"), r.stderr
    assert (venv / "share" / "lpv_sysid" / "config" / "quadrotor.yaml").is_file()


def test_installed_command_loads_a_shipped_config_and_v_turns_on_debug(pip_installed, tmp_path):
    """`lpv-sysid signals` on a shipped config from another directory; the log level is INFO
    without -v (no DEBUG line on stderr) and DEBUG with -v (the design's per-channel lines)."""
    cli = pip_installed / "lpv-sysid"
    cfg = _run([cli, "config", "signals_phase1.yaml"], cwd=tmp_path, timeout=120).stdout.strip()
    runs = {}
    for flags in ([], ["-v"]):
        out = tmp_path / f"sig{len(flags)}"
        argv = [cli, *flags, "signals", "--config", cfg, "--out", out, "--no-plot"]
        r = _run(argv, cwd=tmp_path, timeout=300)
        assert r.returncode == 0, r.stderr
        assert (out / "signals.npz").is_file() and f"wrote {out / 'signals.npz'}" in r.stdout
        runs[bool(flags)] = r.stderr
    assert "DEBUG" not in runs[False]
    site = _site_packages(pip_installed / "python")[0]
    assert "DEBUG lpv_sysid.cli.main: lpv_sysid 0.1.0 (Python" in runs[True]
    assert f"from {site / 'lpv_sysid'}: signals" in runs[True]
    assert "DEBUG lpv_sysid.signals.multisine.generator: channel " in runs[True]


def test_editable_install_puts_the_command_in_bin_running_the_working_tree(
    editable_installed, source_copy, tmp_path
):
    """The README's set-up (make: an editable install into .venv): setup.cfg's colcon
    script dir does not apply to a PEP 660 install either; the command reads the configs of
    the tree it was installed from, through the config/ link as well."""
    cli = editable_installed / "lpv-sysid"
    assert cli.is_file() and not (editable_installed.parent / "lib" / "lpv_sysid").exists()
    r = _run([cli, "config", "quadrotor.yaml"], cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    path = Path(r.stdout.strip())
    assert path == source_copy / "lpv_sysid" / "config" / "quadrotor.yaml"
    assert (source_copy / "config").is_symlink()
    assert (source_copy / "config" / "quadrotor.yaml").resolve() == path.resolve()


# ----------------------------------------------------------------------- colcon, real ROS 2
def test_ros2_run_finds_the_cli_and_its_configs_in_the_colcon_install(tmp_path_factory):
    from ros_real import DomainId, RosEnv, build_package, find_ros

    setup, reason = find_ros()
    if setup is None:
        pytest.skip(reason)
    ws = build_package(setup, tmp_path_factory.mktemp("ros_ws"))
    domain = DomainId(start=os.getpid() % 100)
    try:
        ros = RosEnv(setup, ws, domain.value)
        elsewhere = tmp_path_factory.mktemp("elsewhere")
        r = ros.run("ros2 run lpv_sysid lpv-sysid --help", cwd=elsewhere, timeout=120)
        assert r.returncode == 0 and "usage: lpv-sysid" in r.stdout, r.stderr
        r = ros.run(
            "ros2 run lpv_sysid lpv-sysid config quadrotor.yaml"
            " && ros2 pkg prefix --share lpv_sysid",
            cwd=elsewhere,
            timeout=120,
        )
    finally:
        domain.release()
    assert r.returncode == 0, r.stderr
    package_file, share = (Path(line) for line in r.stdout.split())
    install = ws / "install" / "lpv_sysid"
    assert package_file.is_relative_to(install / "lib") and package_file.is_file()
    assert share == install / "share" / "lpv_sysid"
    assert (share / "config" / "quadrotor.yaml").read_bytes() == package_file.read_bytes()
