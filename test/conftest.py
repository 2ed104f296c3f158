"""Shared pytest configuration: make the repo importable; which rclpy the tests import.

In-process, the tests use the in-repo stand-in (``test/support``: rclpy with a simulated
clock and the common_interfaces messages), put first on ``sys.path`` -- also when a ROS 2
is sourced (every ROS user's shell): a sourced Jazzy puts its rclpy and message packages on
PYTHONPATH, and the tests built on the stand-in's simulated clock (``rclpy._standin``)
would not import. The real ROS 2 is exercised by the real-ROS tests
(``test_ros_real.py``, ``test_mavros_real.py``), which run ``ros2`` and the nodes in
sourced subprocesses with ROS's own ``python3`` (test/support/ros_real.py), and
``test_standin_is_no_kinder_than_rclpy`` holds the stand-in to real rclpy.

``LPV_SYSID_TEST_RCLPY=real``: the real rclpy in-process instead, when it imports in this
interpreter; the stand-in test files are then skipped as a whole (reason in the report;
named on the command line too), and the header lists them.
"""

import importlib.util
import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SUPPORT = os.path.join(ROOT, "test", "support")
HERE = os.path.dirname(os.path.abspath(__file__))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)
#: the opt-in to the real rclpy in-process
ENV = "LPV_SYSID_TEST_RCLPY"


def _real_rclpy_imports() -> bool:
    """A real rclpy that imports in this interpreter (a sourced ROS built for another Python,
    or lacking a library, is none: the stand-in is used)."""
    if importlib.util.find_spec("rclpy") is None:
        return False
    try:
        import rclpy  # noqa: F401
    except Exception:  # ImportError, or an extension that does not load
        for m in [m for m in sys.modules if m == "rclpy" or m.startswith("rclpy.")]:
            del sys.modules[m]
        return False
    return True


WANT_REAL = os.environ.get(ENV, "") == "real"
REAL_RCLPY = WANT_REAL and _real_rclpy_imports()
if not REAL_RCLPY:
    if SUPPORT in sys.path:
        sys.path.remove(SUPPORT)
    sys.path.insert(0, SUPPORT)  # before a sourced ROS's PYTHONPATH
elif SUPPORT not in sys.path:
    # the stand-in's non-ROS helpers (e.g. lpv_test_gains) stay importable, after ROS
    sys.path.append(SUPPORT)


def _uses_standin(path: str) -> bool:
    with open(path, encoding="utf-8") as f:
        return "rclpy._standin" in f.read()


#: under a real rclpy in-process, the test files built on the stand-in's simulated clock
STANDIN_FILES = (
    sorted(
        f
        for f in os.listdir(HERE)
        if f.startswith("test_") and f.endswith(".py") and _uses_standin(os.path.join(HERE, f))
    )
    if REAL_RCLPY
    else []
)
STANDIN_SKIP = f"built on the rclpy stand-in's simulated clock; {ENV}=real uses the real rclpy"


class _StandinOnly(pytest.Module):
    """A stand-in test file under a real rclpy: skipped as a whole, not imported (its
    ``import rclpy._standin`` would fail the collection) -- also when named on the command
    line, where pytest's ``collect_ignore`` does not apply."""

    def collect(self):
        pytest.skip(STANDIN_SKIP)


@pytest.hookimpl(tryfirst=True)
def pytest_pycollect_makemodule(module_path, parent):
    if module_path.name in STANDIN_FILES and str(module_path.parent) == HERE:
        return _StandinOnly.from_parent(parent, path=module_path)
    return None


def pytest_report_header(config):
    if REAL_RCLPY:
        return [
            f"rclpy: real, in-process ({ENV}=real; {len(STANDIN_FILES)} stand-in test "
            f"files skipped: {', '.join(STANDIN_FILES)})"
        ]
    sourced = os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)[0]
    why = (
        f"{ENV}=real but the sourced rclpy does not import here"
        if WANT_REAL
        else f"{ENV}=real for the real one"
    )
    ros = (
        f"sourced ROS 2 ({sourced}) only in the real-ROS tests' subprocesses"
        if sourced
        else "real-ROS tests look for a ROS 2 setup.bash (test/support/ros_real.py)"
    )
    return [f"rclpy: in-repo stand-in in-process ({why}); {ros}"]
