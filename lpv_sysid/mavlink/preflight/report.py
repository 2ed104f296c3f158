"""Preflight check results and their report: the verdicts (GO / WARN / NO-GO), the
go/no-go decision and the table ``lpv-sysid preflight`` prints
(checks: :mod:`lpv_sysid.mavlink.preflight`).
"""

from __future__ import annotations

from dataclasses import dataclass

GO, WARN, NOGO = "GO", "WARN", "NO-GO"


@dataclass(frozen=True)
class Check:
    name: str
    value: str
    expected: str
    verdict: str
    note: str = ""  # reason and fix (printed below the table)
    #: the verdict is the one of a fact not received (yet): no HEARTBEAT, AUTOPILOT_VERSION,
    #: parameter, stream or health message so far -- not a judged value
    missing: bool = False


def verdict(checks: list[Check]) -> bool:
    return all(c.verdict != NOGO for c in checks)


def format_table(checks: list[Check]) -> str:
    w0 = max(len(c.name) for c in checks)
    w1 = max(len(c.value) for c in checks)
    w2 = max(len(c.expected) for c in checks)
    lines = [
        f"{'check':<{w0}}  {'value':<{w1}}  {'expected':<{w2}}  verdict",
        f"{'-' * w0}  {'-' * w1}  {'-' * w2}  -------",
    ]
    lines += [f"{c.name:<{w0}}  {c.value:<{w1}}  {c.expected:<{w2}}  {c.verdict}" for c in checks]
    notes = [f"  {c.verdict} {c.name}: {c.note}" for c in checks if c.note]
    if notes:
        lines += ["", "notes:"] + notes
    return "\n".join(lines)
