"""`lpv-sysid -v / -q`: the log level of a run, set once in cli/main.py.

INFO by default (progress), DEBUG with -v, WARNING with -q, ERROR with -qq; the level is
restored when main returns, and a subcommand that runs others through main (demo) keeps the
outer run's level. Before, -v mapped to INFO, the default: it changed nothing.
"""

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

import lpv_sysid.cli.data.config as config_command
from lpv_sysid.cli.main import EXIT_BAD_INPUT, logging_level, main

ROOT = Path(__file__).resolve().parents[1]
PROBE = "lpv_sysid.test_probe"


def _levels_seen(caplog, monkeypatch, argv: list[str], nested: list[str] | None = None):
    """Levels of the probe records that pass the root level while ``config`` runs (its run
    replaced by one logging at every level; with ``nested``, a main(nested) first)."""

    calls = []

    def probe_run(args):
        calls.append(args.names)
        if nested is not None and len(calls) == 1:
            assert main(nested) == 0
        log = logging.getLogger(PROBE)
        for level in (logging.DEBUG, logging.INFO, logging.WARNING, logging.ERROR):
            log.log(level, "probe %s", logging.getLevelName(level))
        return 0

    monkeypatch.setattr(config_command, "run", probe_run)
    caplog.clear()
    assert main(argv) == 0
    return [r.levelname for r in caplog.records if r.name == PROBE]


@pytest.mark.parametrize(
    "flags, levels",
    [
        ([], ["INFO", "WARNING", "ERROR"]),
        (["-v"], ["DEBUG", "INFO", "WARNING", "ERROR"]),
        (["--verbose"], ["DEBUG", "INFO", "WARNING", "ERROR"]),
        (["-q"], ["WARNING", "ERROR"]),
        (["-qq"], ["ERROR"]),
        (["-qqq"], ["ERROR"]),  # errors are never hidden
    ],
)
def test_v_and_q_set_the_level_of_the_run(caplog, monkeypatch, flags, levels):
    root = logging.getLogger()
    before = root.level
    assert _levels_seen(caplog, monkeypatch, [*flags, "config"]) == levels
    assert root.level == before  # restored: a later caller's logging is untouched


def test_a_nested_main_keeps_the_outer_runs_level(caplog, monkeypatch):
    """demo runs every step through main(argv) without -v: the steps' DEBUG records still
    show under `lpv-sysid -v demo`."""
    seen = _levels_seen(caplog, monkeypatch, ["-v", "config"], nested=["config", "x.yaml"])
    # the nested call ran the probe too (its argv has no -v), then the outer one
    assert seen == ["DEBUG", "INFO", "WARNING", "ERROR"] * 2


def test_logging_level_mapping():
    assert logging_level() == logging.INFO
    assert logging_level(verbose=1) == logging_level(verbose=3) == logging.DEBUG
    assert logging_level(quiet=1) == logging.WARNING
    assert logging_level(quiet=2) == logging_level(quiet=5) == logging.ERROR


def test_v_and_q_together_are_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["-v", "-q", "config"])
    assert exc.value.code == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not allowed with argument" in err[0]


def _cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "lpv_sysid.cli", *argv],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )


def test_a_process_logs_to_stderr_one_line_per_record_and_keeps_stdout_for_results():
    """Without a logging set-up of its own (a real run) main adds the stderr handler."""
    quiet = _cli("config", "quadrotor.yaml")
    loud = _cli("-v", "config", "quadrotor.yaml")
    assert quiet.returncode == loud.returncode == 0
    assert quiet.stdout == loud.stdout == f"{ROOT / 'lpv_sysid' / 'config' / 'quadrotor.yaml'}\n"
    assert quiet.stderr == ""
    lines = loud.stderr.splitlines()
    assert lines[0].startswith("DEBUG lpv_sysid.cli.main: lpv_sysid ")
    assert lines[-1] == (
        "DEBUG lpv_sysid.configuration.defaults: shipped default "
        f"{ROOT}/lpv_sysid/config/quadrotor.yaml"
    )
