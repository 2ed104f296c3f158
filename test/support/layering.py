"""The import graph of a package, read with ``ast``, and the layering rules of
docs/ARCHITECTURE.md section 2 checked on it (used by test/test_layering.py).

Every import counts: module level, inside functions, under ``if TYPE_CHECKING:`` -- a
circle through annotations is still a circle for a reader. :func:`violations` returns one
line per broken rule, so a failing test names the module and the rule.
"""

from __future__ import annotations

import ast
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

#: at most this many modules (``__init__.py`` not counted) in one folder
MAX_MODULES = 12


@dataclass
class Package:
    """The modules of one package tree: dotted name -> file, and who imports whom."""

    root: Path
    name: str
    files: dict[str, Path] = field(default_factory=dict)
    edges: dict[str, set[str]] = field(default_factory=dict)
    #: (importer, module named in the statement, imported name, line)
    name_imports: list[tuple[str, str, str, int]] = field(default_factory=list)

    def is_package(self, mod: str) -> bool:
        return self.files[mod].name == "__init__.py"


def read_package(root: Path, name: str) -> Package:
    """The :class:`Package` under ``root / name`` (``root``: the directory that holds it)."""
    pkg = Package(root, name)
    for path in sorted((root / name).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        pkg.files[".".join(parts)] = path
    for mod, path in pkg.files.items():
        pkg.edges[mod] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            for target, names in _targets(pkg, mod, node):
                owner = _owning_module(pkg, target)
                if owner is not None and owner != mod:
                    pkg.edges[mod].add(owner)
                for n in names:
                    pkg.name_imports.append((mod, target, n, getattr(node, "lineno", 0)))
    return pkg


def _targets(pkg: Package, mod: str, node: ast.AST):
    """(dotted module, names imported from it) for an import statement of ``pkg``."""
    if isinstance(node, ast.Import):
        for a in node.names:
            if a.name == pkg.name or a.name.startswith(pkg.name + "."):
                yield a.name, []
    elif isinstance(node, ast.ImportFrom):
        base = node.module or ""
        if node.level:
            here = mod.split(".")
            if not pkg.is_package(mod):
                here = here[:-1]
            here = here[: len(here) - (node.level - 1)]
            base = ".".join(here + ([node.module] if node.module else []))
        if base != pkg.name and not base.startswith(pkg.name + "."):
            return
        names = []
        for a in node.names:
            sub = f"{base}.{a.name}"
            if sub in pkg.files:
                yield sub, []
            else:
                names.append(a.name)
        if names:
            yield base, names


def _owning_module(pkg: Package, dotted: str) -> str | None:
    while dotted and dotted not in pkg.files:
        dotted = dotted.rpartition(".")[0]
    return dotted or None


def cycles(pkg: Package) -> list[list[str]]:
    """The import circles: strongly connected components with more than one module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(pkg.files) + 100))

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(pkg.edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    try:
        for v in sorted(pkg.edges):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return out


def read_layers(markdown: Path) -> dict[str, int]:
    """``{package: layer}`` from the fenced ``layers`` block of docs/ARCHITECTURE.md
    (lines ``N  pkg [pkg ...]  description``; a package is a word with dots)."""
    text = markdown.read_text(encoding="utf-8")
    m = re.search(r"```layers\n(.*?)```", text, re.S)
    if m is None:
        raise ValueError(f"{markdown}: no ```layers block")
    layers: dict[str, int] = {}
    for line in m.group(1).splitlines():
        fields = line.split()
        if not fields:
            continue
        level = int(fields[0])
        for word in fields[1:]:
            if not re.fullmatch(r"[a-z_]+(\.[a-z_]+)*", word):
                break
            layers[word] = level
    return layers


def layer_of(pkg: Package, mod: str, layers: dict[str, int]) -> tuple[int, str] | None:
    """(layer, the table's package) of ``mod``: the longest table entry containing it; the
    root package itself is below every layer (None: not in the table)."""
    rel = mod[len(pkg.name) + 1 :] if mod != pkg.name else ""
    if not rel:
        return -1, pkg.name
    parts = rel.split(".")
    for n in range(len(parts), 0, -1):
        key = ".".join(parts[:n])
        if key in layers:
            return layers[key], key
    return None


def faces(pkg: Package) -> dict[str, set[str]]:
    """``{package: names in its __all__}`` of every package that exports names."""
    out = {}
    for mod, path in pkg.files.items():
        if not pkg.is_package(mod):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in tree.body:
            if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets
            ):
                out[mod] = set(ast.literal_eval(node.value))
    return out


def violations(pkg: Package, layers: dict[str, int]) -> list[str]:
    """Every broken rule, one line each (empty: the package is layered)."""
    bad: list[str] = [f"import circle: {' -> '.join(c)}" for c in cycles(pkg)]
    for mod, targets in sorted(pkg.edges.items()):
        mine = layer_of(pkg, mod, layers)
        if mine is None:
            bad.append(f"{mod}: not in the layer table of docs/ARCHITECTURE.md")
            continue
        for t in sorted(targets):
            theirs = layer_of(pkg, t, layers)
            if theirs is None:
                continue  # reported for t itself
            if theirs[0] > mine[0]:
                bad.append(f"upward import: {mod} (layer {mine[0]}) -> {t} (layer {theirs[0]})")
            elif theirs[0] == mine[0] and theirs[1] != mine[1]:
                bad.append(f"import within layer {mine[0]}: {mod} -> {t}")
            if t != pkg.name and pkg.is_package(t) and mod.startswith(t + "."):
                bad.append(f"part imports its own face: {mod} -> {t}")
    for mod, path in sorted(pkg.files.items()):
        if pkg.is_package(mod):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in tree.body:
            if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets
            ):
                bad.append(f"{mod}: __all__ outside a face (re-exports belong in __init__.py)")
            if isinstance(node, ast.ImportFrom):
                for a in node.names:
                    if a.asname is not None and a.asname == a.name:
                        bad.append(f"{mod}: re-export 'import {a.name} as {a.name}'")
    folders: dict[Path, int] = {}
    for path in pkg.files.values():
        if path.name != "__init__.py":
            folders[path.parent] = folders.get(path.parent, 0) + 1
    for folder, n in sorted(folders.items()):
        if n > MAX_MODULES:
            bad.append(f"{folder}: {n} modules (at most {MAX_MODULES} per folder)")
    return bad


def second_paths(pkg: Package, importers: dict[str, Path]) -> list[str]:
    """Imports of a name a face exports from one of that face's parts, by a module outside
    the face's package: every public name has one import path."""
    exported = faces(pkg)
    bad = []
    for importer, path in sorted(importers.items()):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if not isinstance(node, ast.ImportFrom) or node.level:
                continue
            module = node.module or ""
            if module not in pkg.files or pkg.is_package(module):
                continue
            face = module.rpartition(".")[0]
            if face not in exported or importer == face or importer.startswith(face + "."):
                continue
            for a in node.names:
                if a.name in exported[face]:
                    bad.append(
                        f"{importer}:{node.lineno}: '{a.name}' from {module}; "
                        f"import it from the face {face}"
                    )
    return bad
