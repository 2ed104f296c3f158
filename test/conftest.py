"""Shared pytest configuration: make the repo importable; the rclpy stand-in only as fallback.

When a real ROS 2 (rclpy) is importable — the user sourced ``setup.bash`` and runs pytest
with ROS's Python — it is used and the stand-in (``test/support``: rclpy and the
common_interfaces messages) stays off ``sys.path``; tests that need the stand-in's
simulated clock are not collected (listed in the report header), and the real-ROS
tests (``test_ros_real.py``) run the node graph as processes. Without rclpy the stand-in
is put first on ``sys.path``.
"""

import importlib.util
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SUPPORT = os.path.join(ROOT, "test", "support")
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


def _real_rclpy_imports() -> bool:
    """A real rclpy that imports in this interpreter: a sourced ROS whose compiled rclpy was
    built for another Python (or lacks a library) is no real rclpy here -- the stand-in is
    used instead of failing the whole collection."""
    if importlib.util.find_spec("rclpy") is None:
        return False
    try:
        import rclpy  # noqa: F401
    except Exception:  # ImportError, or an extension that does not load
        for m in [m for m in sys.modules if m == "rclpy" or m.startswith("rclpy.")]:
            del sys.modules[m]
        return False
    return True


REAL_RCLPY = _real_rclpy_imports()
if not REAL_RCLPY and SUPPORT not in sys.path:
    sys.path.insert(0, SUPPORT)
elif REAL_RCLPY and SUPPORT not in sys.path:
    # the stand-in's non-ROS helpers (e.g. lpv_test_gains) stay importable, after ROS
    sys.path.append(SUPPORT)


def _uses_standin(path: str) -> bool:
    with open(path, encoding="utf-8") as f:
        return "rclpy._standin" in f.read()


# Under a real rclpy, test files built on the stand-in's simulated clock are not collected
# (they would import rclpy._standin); pytest -ra lists nothing for them, so say it once.
collect_ignore = []
if REAL_RCLPY:
    here = os.path.dirname(os.path.abspath(__file__))
    collect_ignore = sorted(
        f
        for f in os.listdir(here)
        if f.startswith("test_") and f.endswith(".py") and _uses_standin(os.path.join(here, f))
    )


def pytest_report_header(config):
    if REAL_RCLPY:
        return [
            f"rclpy: real ({len(collect_ignore)} stand-in test files not collected: "
            f"{', '.join(collect_ignore)})"
        ]
    return ["rclpy: in-repo stand-in (test/support); real-ROS tests skip"]
