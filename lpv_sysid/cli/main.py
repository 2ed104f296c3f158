"""`lpv-sysid` entry point: a registry of subcommands.

Each module in ``lpv_sysid.cli`` that defines ``COMMAND`` (the subcommand name),
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int`` is a
subcommand. Modules are discovered, so adding a subcommand never edits this file.

Errors derived from :class:`lpv_sysid.errors.LpvSysidError` (bad input) are
printed as one line on stderr and exit with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys
from types import ModuleType
from typing import Sequence

from lpv_sysid import __version__
from lpv_sysid.errors import LpvSysidError

EXIT_BAD_INPUT = 2


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line and exit 2."""

    def error(self, message: str) -> None:  # noqa: D401 - argparse API
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def discover_commands() -> dict[str, ModuleType]:
    """Import every ``lpv_sysid.cli`` module that declares a ``COMMAND``."""
    import lpv_sysid.cli as pkg

    commands: dict[str, ModuleType] = {}
    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda i: i.name):
        if info.name.startswith("_") or info.name == "main":
            continue
        module = importlib.import_module(f"{pkg.__name__}.{info.name}")
        name = getattr(module, "COMMAND", None)
        if name is None:
            continue
        if name in commands:
            raise RuntimeError(f"duplicate CLI command {name!r} in {module.__name__}")
        commands[name] = module
    return commands


def build_parser(commands: dict[str, ModuleType]) -> argparse.ArgumentParser:
    parser = _Parser(prog="lpv-sysid", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"lpv_sysid {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, module in sorted(commands.items()):
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    commands = discover_commands()
    parser = build_parser(commands)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2) if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    if args.command is None:
        parser.print_help()
        return EXIT_BAD_INPUT
    try:
        return int(args._run(args) or 0)
    except LpvSysidError as exc:
        print(f"lpv-sysid {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
