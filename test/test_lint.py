"""Linters as tests (the ros2/examples habit): ruff (pycodestyle + pyflakes at the
ament line length of 99, rules in ``ruff.toml``), the ruff formatter, and mypy on the
typed package (``py.typed`` is shipped; settings in ``setup.cfg`` ``[mypy]``).

The tools are pinned in requirements.txt, so ``make test`` always runs them; an
environment without them (a bare colcon test under ROS) skips with one line.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Everything Python that the repository ships or runs.
TREES = ["lpv_sysid", "test", "bench", "launch", "setup.py"]


def _tool(module: str) -> list[str]:
    """Command prefix running ``module`` from the interpreter running the tests."""
    try:
        __import__(module)
    except ImportError:
        pytest.skip(f"{module} not installed (pinned in requirements.txt)")
    return [sys.executable, "-m", module]


def _run(cmd: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)


def test_ruff_check_is_clean() -> None:
    res = _run(_tool("ruff") + ["check", "--no-cache", *TREES])
    assert res.returncode == 0, res.stdout + res.stderr


def test_ruff_format_is_applied() -> None:
    res = _run(_tool("ruff") + ["format", "--check", "--no-cache", *TREES])
    assert res.returncode == 0, "run `ruff format .`:\n" + res.stdout + res.stderr


def test_mypy_on_the_typed_package() -> None:
    assert (ROOT / "lpv_sysid" / "py.typed").is_file()
    res = _run(_tool("mypy") + ["--config-file", "setup.cfg", "--no-incremental"])
    assert res.returncode == 0, res.stdout + res.stderr
    assert "Success" in res.stdout


def test_the_linters_find_a_planted_defect(tmp_path: Path) -> None:
    """The checks above can fail: a long line, an unused import and a type error in a
    scratch file are each reported."""
    bad = tmp_path / "bad.py"
    bad.write_text("import os\n\n\ndef f(x: int) -> str:\n    return x  # " + "z" * 99 + "\n")
    res = _run(_tool("ruff") + ["check", "--no-cache", str(bad)])
    assert "E501" in res.stdout and "F401" in res.stdout, res.stdout
    res = _run(_tool("mypy") + ["--no-incremental", "--config-file", "/dev/null", str(bad)])
    assert 'Incompatible return value type (got "int", expected "str")' in res.stdout
