"""`lpv-sysid` entry point: a registry of subcommands.

Each module in ``lpv_sysid.cli`` that defines ``COMMAND`` (the subcommand name),
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int`` is a
subcommand. Modules are discovered, so adding a subcommand never edits this file.

Exit status: what ``run`` returns (0, or 1 where a subcommand defines it, e.g. ``verify``
"verification failed", ``preflight`` NO-GO, ``replay`` safety abort). Everything that ends a
subcommand by an exception is **one line on stderr and status 2**: errors derived from
:class:`lpv_sysid.errors.LpvSysidError` (bad input, named by the raiser), and any other
exception escaping a subcommand (``OSError``, ``MemoryError``, ``RecursionError``,
``UnicodeError``, ``ValueError``, ...: a hostile input that slipped past the checks), which
is described with its type and the input files of the command; its traceback is logged only
with ``-v``. Status 1 therefore always means a subcommand's own verdict, never a crash.
Ctrl-C gives one line and status 130.

Logging is configured here, once per run (:func:`logging_level`, :func:`configured_logging`):
INFO by default (progress of the long steps), DEBUG with ``-v``, WARNING with ``-q``
(ERROR with ``-qq``), one ``LEVEL logger: message`` line per record on stderr; stdout stays
the command's results. A subcommand that runs others through :func:`main` (``demo``) keeps
the outer run's logging.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import pkgutil
import re
import sys
import traceback
import warnings
from pathlib import Path
from types import ModuleType
from typing import Iterator, NoReturn, Sequence

from lpv_sysid import __version__
from lpv_sysid.errors import LpvSysidError

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130

#: format of a log line on stderr
LOG_FORMAT = "%(levelname)s %(name)s: %(message)s"

log = logging.getLogger(__name__)

#: set while :func:`configured_logging` is in force (a nested :func:`main` leaves it alone)
_logging_configured = False


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line and exit 2."""

    def error(self, message: str) -> NoReturn:  # argparse API: never returns
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


#: ``COMMAND = "name"`` at the start of a line of a command module's source
_COMMAND_LINE = re.compile(r"""^COMMAND = ["']([^"']+)["']""", re.MULTILINE)


def discover_commands(only: str | None = None) -> dict[str, ModuleType]:
    """Import every module of ``lpv_sysid.cli`` and its subpackages that declares a
    ``COMMAND``. ``only``: import just the module whose source declares ``COMMAND = "only"``
    (a run of one command: the other commands' imports cost ~2 s of start-up); every module
    when none does."""
    here = Path(__file__).resolve().parent
    commands: dict[str, ModuleType] = {}
    if only is not None:  # the file system, not pkgutil (which imports every subpackage)
        for path in sorted(here.rglob("*.py")):
            if not path.stem.startswith("_") and _declares(path, only):
                rel = path.relative_to(here).with_suffix("").parts
                module = importlib.import_module(".".join((__package__, *rel)))
                if getattr(module, "COMMAND", None) == only:
                    return {only: module}
    infos = sorted(
        pkgutil.walk_packages([str(here)], prefix=f"{__package__}."),
        key=lambda i: i.name.rsplit(".", 1)[-1],
    )
    for info in infos:
        leaf = info.name.rsplit(".", 1)[-1]
        if info.ispkg or leaf.startswith("_") or leaf == "main":
            continue
        module = importlib.import_module(info.name)
        name = getattr(module, "COMMAND", None)
        if name is None:
            continue
        if name in commands:
            raise RuntimeError(f"duplicate CLI command {name!r} in {module.__name__}")
        commands[name] = module
    return commands


def _declares(path: Path, command: str) -> bool:
    """Whether the source at ``path`` declares ``COMMAND = command``."""
    try:
        return command in _COMMAND_LINE.findall(path.read_text(encoding="utf-8"))
    except OSError:
        return False


DESCRIPTION = (
    "Safe large-domain system identification of an unstable multirotor with robust LPV "
    "control (Hopwood & Woolsey): the offline commands. Global options go before COMMAND "
    "(lpv-sysid -v COMMAND ...)."
)


def build_parser(commands: dict[str, ModuleType]) -> argparse.ArgumentParser:
    parser = _Parser(prog="lpv-sysid", description=DESCRIPTION)
    parser.add_argument("--version", action="version", version=f"lpv_sysid {__version__}")
    loud = parser.add_mutually_exclusive_group()
    loud.add_argument(
        "-v", "--verbose", action="count", default=0, help="debug log output (default: INFO)"
    )
    loud.add_argument(
        "-q", "--quiet", action="count", default=0, help="warnings only (-qq: errors only)"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, module in sorted(commands.items()):
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
        _add_force(p)
    return parser


def _add_force(p: argparse.ArgumentParser) -> None:
    """``--force`` on every (sub)parser with an ``--out``: the one switch of
    :func:`_guard_output` (and of outputs a command refuses to replace)."""
    dests = {a.dest for a in p._actions}
    if "out" in dests and "force" not in dests:
        p.add_argument(
            "--force",
            action="store_true",
            help="write --out even where it is an input of this run or replaces files "
            "a certificate refers to",
        )
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            for child in a.choices.values():
                _add_force(child)


def _guard_output(args: argparse.Namespace) -> None:
    """Every command: an ``--out`` that is one of the run's input files, or a file a gains
    certificate among them refers to (its sidecar), is refused (unless ``--force``):
    :func:`lpv_sysid.io.files.refuse_overwrite` against every argument that names an
    existing file."""
    out = getattr(args, "out", None)
    if out is None:
        return
    from lpv_sysid.io.files import refuse_overwrite
    from lpv_sysid.io.formats import referenced_files

    inputs = [(a, b) for a, b in (s.split(" ", 1) for s in _inputs(args))]
    # and the files a certificate among them refers to (verify --out gains.cert.npz)
    inputs += [
        (f"(sidecar of {a} {b})", str(f)) for a, b in list(inputs) for f in referenced_files(b)
    ]
    refuse_overwrite(out, inputs, bool(getattr(args, "force", False)), force_hint="--force")


#: commands whose linear algebra is many small problems: there OpenBLAS' second thread costs
#: CPU and saves no wall time (measured both ways by bench/bench_ident.py and, for the studies
#: that use every core through worker processes instead, bench/bench_studies.py; BENCHMARKS.md)
SINGLE_THREAD_BLAS = (
    "identify",
    "identify-nonlinear",
    "vrft",
    "simulate",
    "demo",
    "coverage",
    "verify",
)


def _command_word(argv: Sequence[str]) -> str | None:
    """The COMMAND of a command line (global options come before it and take no value)."""
    return next((a for a in argv if not a.startswith("-")), None)


def _single_thread_blas(argv: Sequence[str]) -> None:
    """``OPENBLAS_NUM_THREADS=1`` for :data:`SINGLE_THREAD_BLAS`, set before numpy is imported
    (OpenBLAS reads it once, when it loads); a value already in the environment wins."""
    if "numpy" in sys.modules:
        return
    if _command_word(argv) in SINGLE_THREAD_BLAS:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def main(argv: Sequence[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else argv
    _single_thread_blas(words)
    commands = discover_commands(_command_word(words))
    parser = build_parser(commands)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_BAD_INPUT
    with configured_logging(logging_level(args.verbose, args.quiet)):
        log.debug(
            "lpv_sysid %s (Python %s) from %s: %s",
            __version__,
            sys.version.split()[0],
            Path(__file__).resolve().parents[1],
            args.command,
        )
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    """``args._run(args)`` with the exit-status layer (module docstring)."""
    shown = warnings.showwarning
    warnings.showwarning = _warning_line  # a Python warning is one log line, not source text
    try:
        _guard_output(args)
        return int(args._run(args) or 0)
    except LpvSysidError as exc:
        return _fail(args, str(exc))
    except KeyboardInterrupt:
        return _fail(args, "interrupted", EXIT_INTERRUPTED)
    except Exception as exc:  # noqa: BLE001 - the exit-status layer: no traceback, never status 1
        if args.verbose:  # the traceback only on request, before the one-line verdict
            traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)
        return _fail(args, describe_unexpected(exc, _inputs(args)))
    finally:
        warnings.showwarning = shown


def logging_level(verbose: int = 0, quiet: int = 0) -> int:
    """The root log level for ``-v`` x ``verbose`` / ``-q`` x ``quiet``: INFO by default,
    DEBUG with ``-v``, WARNING with ``-q``, ERROR with ``-qq``."""
    if verbose:
        return logging.DEBUG
    return min(logging.INFO + 10 * quiet, logging.ERROR)


@contextlib.contextmanager
def configured_logging(level: int) -> Iterator[None]:
    """Root logger at ``level`` for the duration of one run, restored afterwards.

    A stderr handler (:data:`LOG_FORMAT`) is added only when the root logger has none: an
    application that calls :func:`main` with its own logging set up (pytest's capture,
    a ROS launch) keeps its handlers and only gets the level. Inside a run (a nested
    :func:`main`) nothing changes."""
    global _logging_configured
    if _logging_configured:
        yield
        return
    root = logging.getLogger()
    previous = root.level
    handler = None
    if not root.handlers:
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter(LOG_FORMAT))
        root.addHandler(handler)
    root.setLevel(level)
    _logging_configured = True
    try:
        yield
    finally:
        _logging_configured = False
        root.setLevel(previous)
        if handler is not None:
            root.removeHandler(handler)


def _warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    logging.getLogger("py.warnings").warning(
        "%s: %s (%s:%s)",
        category.__name__,
        one_line(str(message)),
        os.path.basename(str(filename)),
        lineno,
    )


def _fail(args: argparse.Namespace, message: str, status: int = EXIT_BAD_INPUT) -> int:
    try:
        sys.stdout.flush()
    except (OSError, ValueError):
        pass
    print(f"lpv-sysid {args.command}: error: {one_line(message)}", file=sys.stderr)
    return status


#: Longest error line printed: messages quote the offending value, which may be megabytes long.
MAX_MESSAGE = 2000


def one_line(message: str) -> str:
    """``message`` with its lines joined by "; " (an error is one line on stderr), its middle cut
    beyond :data:`MAX_MESSAGE` characters."""
    parts = [ln.strip() for ln in str(message).splitlines() if ln.strip()]
    text = "; ".join(parts) if parts else "(no message)"
    if len(text) > MAX_MESSAGE:
        cut = len(text) - MAX_MESSAGE
        head, tail = text[: MAX_MESSAGE // 2], text[-MAX_MESSAGE // 2 :]
        text = f"{head} ... ({cut} characters omitted) ... {tail}"
    return text


def _inputs(args: argparse.Namespace) -> list[str]:
    """``--name value`` of the arguments naming existing files or directories (not ``--out``)."""
    out = []
    for name, value in sorted(vars(args).items()):
        if name.startswith("_") or name in ("out", "command", "mode"):
            continue
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(v, (str, Path)) and str(v):
                try:
                    exists = os.path.lexists(v)
                except (OSError, ValueError):
                    exists = False
                if exists:
                    out.append(f"--{name.replace('_', '-')} {v}")
    return out


def describe_unexpected(exc: BaseException, inputs: Sequence[str] = ()) -> str:
    """One-line description of an exception no check turned into an LpvSysidError."""
    if isinstance(exc, OSError):
        where = " -> ".join(str(f) for f in (exc.filename, exc.filename2) if f is not None)
        what = exc.strerror or str(exc) or type(exc).__name__
        text = f"{where}: {what}" if where else f"{type(exc).__name__}: {what}"
    elif isinstance(exc, MemoryError):
        text = "out of memory (an input is too large for this machine)"
    elif isinstance(exc, RecursionError):
        text = "an input is nested too deeply (RecursionError)"
    else:
        text = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    if inputs and not isinstance(exc, OSError):
        text += f" (inputs: {', '.join(inputs)})"
    return text + " [rerun with -v for the traceback]"


if __name__ == "__main__":
    sys.exit(main())
