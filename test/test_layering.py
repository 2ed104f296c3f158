"""The package is layered as docs/ARCHITECTURE.md section 2 says (its ``layers`` table is
read here, so the document and the check cannot drift apart): no import circles, no import
from a higher layer or across packages of one layer, no part importing its own face, no
re-export outside a face, at most 12 modules per folder, and one import path per public
name. The checker itself is tested on small packages that break each rule."""

from __future__ import annotations

from pathlib import Path

import pytest
from layering import read_layers, read_package, second_paths, violations

ROOT = Path(__file__).resolve().parents[1]
LAYERS = read_layers(ROOT / "docs" / "ARCHITECTURE.md")


def test_layer_table_names_the_package_tree():
    tops = {p.name for p in (ROOT / "lpv_sysid").iterdir() if (p / "__init__.py").is_file()}
    tops |= {p.stem for p in (ROOT / "lpv_sysid").glob("*.py") if p.name != "__init__.py"}
    assert tops <= {k.split(".")[0] for k in LAYERS}
    assert LAYERS["errors"] == 0 and LAYERS["cli"] == LAYERS["nodes"] == max(LAYERS.values())


def test_lpv_sysid_is_layered():
    assert violations(read_package(ROOT, "lpv_sysid"), LAYERS) == []


def test_every_public_name_has_one_import_path():
    pkg = read_package(ROOT, "lpv_sysid")
    importers = dict(pkg.files)
    for folder in ("test", "bench", "launch"):
        for p in (ROOT / folder).rglob("*.py"):
            importers[f"{folder}.{p.stem}"] = p
    assert second_paths(pkg, importers) == []


# ----------------------------------------------------------------- the checker on bad trees
def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        p = tmp_path / "pkg" / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return tmp_path


TOY_LAYERS = {"low": 0, "high": 1, "other": 1}


@pytest.mark.parametrize(
    "files, expected",
    [
        (  # a circle through a TYPE_CHECKING import still counts
            {
                "low/a.py": "from pkg.low import b\n",
                "low/b.py": "from typing import TYPE_CHECKING\n"
                "if TYPE_CHECKING:\n    from pkg.low.a import X\n",
            },
            "import circle: pkg.low.a -> pkg.low.b",
        ),
        ({"low/a.py": "def f():\n    from pkg.high import c\n"}, "upward import: pkg.low.a"),
        ({"high/c.py": "import pkg.other.d\n", "other/d.py": ""}, "import within layer 1"),
        (
            {
                "low/x/__init__.py": "from pkg.low.x.p import v\n",
                "low/x/p.py": "import pkg.low.x\n",
            },
            "part imports its own face: pkg.low.x.p -> pkg.low.x",
        ),
        ({"low/a.py": "from pkg.low.b import v as v\n"}, "re-export 'import v as v'"),
        ({"low/a.py": "__all__ = ['f']\n"}, "__all__ outside a face"),
        ({f"low/m{i}.py": "" for i in range(12)}, "13 modules (at most 12 per folder)"),
        ({"elsewhere/a.py": ""}, "pkg.elsewhere.a: not in the layer table"),
    ],
)
def test_checker_reports_each_broken_rule(tmp_path, files, expected):
    base = {"__init__.py": "", "low/__init__.py": "", "high/__init__.py": ""}
    base |= {"other/__init__.py": "", "elsewhere/__init__.py": "", "high/c.py": ""}
    base |= {"low/b.py": "", "low/x/__init__.py": "", "low/x/p.py": "v = 1\n"}
    root = _tree(tmp_path, {**base, **files})
    found = violations(read_package(root, "pkg"), TOY_LAYERS)
    assert any(expected in line for line in found), found


def test_checker_passes_a_layered_tree_and_finds_a_second_path(tmp_path):
    root = _tree(
        tmp_path,
        {
            "__init__.py": "",
            "low/__init__.py": "",
            "low/x/__init__.py": "from pkg.low.x.p import v\n\n__all__ = ['v']\n",
            "low/x/p.py": "v = 1\n",
            "high/__init__.py": "",
            "high/c.py": "from pkg.low.x import v\n",
            "high/d.py": "from pkg.low.x.p import v\n",
        },
    )
    pkg = read_package(root, "pkg")
    assert violations(pkg, TOY_LAYERS) == []
    paths = second_paths(pkg, pkg.files)
    assert len(paths) == 1 and paths[0].startswith("pkg.high.d:1: 'v' from pkg.low.x.p")
