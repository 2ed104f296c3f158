"""Markdown building blocks of the report: tables, the document being written, small formatters.

:class:`Report` collects the lines and figures of ``report.md``; a section that cannot be built
from a malformed input ends with a note instead of failing the report (:meth:`Report.guard`).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.report.data import CANDIDATES, RunData

log = logging.getLogger(__name__)


def md_table(header: Sequence[str], rows: Iterable[Sequence[Any]], fmt: str = "{:.3g}") -> str:
    """GitHub-flavoured Markdown table; floats with ``fmt``, None as '-'."""

    def cell(v: Any) -> str:
        if v is None:
            return "-"
        if isinstance(v, (float, np.floating)):
            return "nan" if not np.isfinite(v) else fmt.format(float(v))
        if isinstance(v, (bool, np.bool_)):
            return "yes" if v else "NO"
        return str(v).replace("|", "\\|")

    lines = [
        "| " + " | ".join(str(h).replace("|", "\\|") for h in header) + " |",
        "|" + "|".join("---" for _ in header) + "|",
    ]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def _flatten(d: Any, prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    if isinstance(d, dict):
        for k, v in d.items():
            out += _flatten(v, f"{prefix}.{k}" if prefix else str(k))
    elif (
        isinstance(d, list) and d and all(isinstance(x, (int, float)) for x in d) and len(d) <= 16
    ):
        out.append((prefix, "[" + ", ".join(f"{x:g}" for x in d) + "]"))
    elif isinstance(d, list) and d and all(isinstance(x, dict) for x in d):
        for i, x in enumerate(d):
            out += _flatten(x, f"{prefix}[{i}]")
    elif isinstance(d, list) and len(d) > 16:
        out.append((prefix, f"<{len(d)} values>"))
    else:
        out.append((prefix, d))
    return out


def kv_table(d: Any) -> str:
    return md_table(["key", "value"], _flatten(d), fmt="{:.6g}")


class Report:
    def __init__(self, data: RunData, out_path: Path) -> None:
        self.data = data
        self.out = Path(out_path)
        self.fig_dir = self.out.parent
        self.lines: list[str] = []
        self.figures: list[Path] = []

    def h(self, level: int, text: str) -> None:
        self.lines += ["", "#" * level + " " + text, ""]

    def p(self, text: str) -> None:
        self.lines += [text, ""]

    def fig(self, path: Path, caption: str) -> None:
        self.figures.append(path)
        self.p(f"![{caption}]({path.name})\n\n*{caption}*")

    def missing(self, key: str) -> None:
        if key in self.data.problems:
            self.p(f"**Input unreadable:** {self.data.problems[key]}")
        else:
            self.p(
                "**Input missing:** none of `"
                + "`, `".join(CANDIDATES[key])
                + "` in the run directory."
            )

    def guard(self, label: str, fn: Callable[[], None]) -> None:
        """Run one section; a malformed (but parseable) file ends that section only."""
        try:
            fn()
        except (ConfigError, KeyError, TypeError, ValueError, IndexError, OSError) as exc:
            log.warning("%s: %s", label, exc)
            self.p(f"**Could not build this section:** {exc}")

    def with_input(self, key: str, label: str, fn: Callable[[], None]) -> bool:
        """``fn()`` under :meth:`guard` when input ``key`` was loaded, else the
        :meth:`missing` note; whether the input was there."""
        if getattr(self.data, key) is None:
            self.missing(key)
            return False
        self.guard(label, fn)
        return True


def get_first(d: dict, *keys: str) -> Any:
    for k in keys:
        if k in d:
            return d[k]
    return None


def short(v: Any) -> Any:
    if isinstance(v, list):
        return (
            "["
            + ", ".join(f"{float(x):g}" if isinstance(x, (int, float)) else str(x) for x in v)
            + "]"
        )
    return v
