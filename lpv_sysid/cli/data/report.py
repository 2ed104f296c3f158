"""`lpv-sysid report`: Markdown report (+ PNG figures) of a run directory.

Opens with the go/no-go table (:mod:`lpv_sysid.report.gonogo`); the verification result is
read from ``RUN/verification.yaml`` (absent: "not verified", NO-GO)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

COMMAND = "report"
HELP = "write a Markdown report with figures from the artefacts of a run directory"


#: argument of the report core -> the command-line flag that sets it (the core's errors
#: name the argument, the CLI's the flag)
FLAG_OF_ARGUMENT = {"run_dir": "--run", "out_path": "--out"}


def with_flag(message: str) -> str:
    """A report core's error message with the flag of the argument it names appended."""
    name = message.split(":", 1)[0]
    return f"{message} [{FLAG_OF_ARGUMENT[name]}]" if name in FLAG_OF_ARGUMENT else message


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", required=True, type=Path, help="run directory (e.g. demo_out)")
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="report path, ending in .md (default: RUN/report/report.md); figures go next to it",
    )
    parser.add_argument(
        "--no-verify",
        action="store_true",
        help="accepted for compatibility, no effect: the report reads verification.yaml "
        "(`lpv-sysid verify` writes it) and never re-runs the verifier",
    )
    parser.add_argument(
        "--strict", action="store_true", help="exit 2 when an input file exists but cannot be read"
    )


def run(args: argparse.Namespace) -> int:
    from lpv_sysid.errors import ConfigError

    try:
        path = _report(args)
    except ConfigError as exc:
        raise ConfigError(with_flag(str(exc))) from None
    print(path)
    return 0


def _report(args: argparse.Namespace) -> Path:
    from lpv_sysid.errors import ConfigError
    from lpv_sysid.report import load_run, write_report

    if args.strict:
        data_log = logging.getLogger("lpv_sysid.report.data")
        level = data_log.level
        data_log.setLevel(logging.ERROR)  # the problems are the one error line, not also warnings
        try:
            problems = load_run(args.run, verify=not args.no_verify).problems
        finally:
            data_log.setLevel(level)
        if problems:
            raise ConfigError("; ".join(problems.values()))
    return write_report(args.run, args.out, verify=not args.no_verify)
