"""CLI registry: every subcommand has --help, usage errors exit 2 with one line."""

import pytest

from lpv_sysid.cli.main import EXIT_BAD_INPUT, discover_commands, main

EXPECTED = {"signals", "simulate", "identify", "synthesize", "verify", "report", "demo"}


def test_expected_commands_registered():
    assert EXPECTED <= set(discover_commands())


@pytest.mark.parametrize("name", sorted(discover_commands()))
def test_every_command_has_help(name, capsys):
    with pytest.raises(SystemExit) as exc:
        main([name, "--help"])
    assert exc.value.code == 0
    assert "usage: lpv-sysid" in capsys.readouterr().out


def test_unknown_command_exits_2_with_one_line(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["no-such-command"])
    assert exc.value.code == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "invalid choice" in err[0]


def test_no_command_exits_2():
    assert main([]) == EXIT_BAD_INPUT
