"""Synthesis reports its progress through logging (INFO per stage), and the cores this session
split (sim/phase2*, sim/excitation_fir, synthesis/hinf_lmi, synthesis/robust_lmi) and the
report core (report/*) name the configuration field or argument in their errors, not a
command-line flag (the CLI maps fields to flags)."""

from __future__ import annotations

import ast
import logging
import re
from pathlib import Path

import pytest

from lpv_sysid.errors import ConfigError, SolverError
from lpv_sysid.synthesis.example_models import uncontrollable_disturbance_plant
from lpv_sysid.synthesis.hinf import HinfOptions, synthesize_hinf

PKG = Path(__file__).resolve().parent.parent / "lpv_sysid"
# Every module outside the command-line layer: the cores (and node shells) name config
# fields and arguments; only lpv_sysid/cli/ maps them to its flags.
CORES = sorted(p for p in PKG.rglob("*.py") if p.relative_to(PKG).parts[0] != "cli")
FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]+")


def _raised_strings(path: Path) -> list[str]:
    """The string constants inside every ``raise`` statement of a module."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Raise) and node.exc is not None:
            out += [
                c.value
                for c in ast.walk(node.exc)
                if isinstance(c, ast.Constant) and isinstance(c.value, str)
            ]
    return out


@pytest.mark.parametrize("path", CORES, ids=lambda p: p.name)
def test_core_errors_name_no_command_line_flag(path):
    flags = [s for s in _raised_strings(path) if FLAG.search(s)]
    assert not flags, f"{path.name}: CLI flag wording in errors: {flags}"


def test_phase2_config_errors_name_the_field():
    from lpv_sysid.sim.phase2 import Phase2Config

    for field, bad in (("ff_filter_tau", -1.0), ("kappa", 0.0), ("storage", "zip")):
        with pytest.raises(ConfigError, match=rf"^(phase2\.)?{field}\b") as ei:
            Phase2Config(**{field: bad})
        assert "--" not in str(ei.value)


def test_synthesize_cli_maps_a_field_to_its_flag():
    from lpv_sysid.cli.design import with_flag

    assert (
        with_flag("hinf.gamma must be > 0, got -1") == "hinf.gamma must be > 0, got -1 [--gamma]"
    )
    assert with_flag("weights.T missing") == "weights.T missing"


def test_synthesis_logs_each_stage_and_the_remedies(caplog):
    """Infeasible at the requested gamma: building, solver start with the problem size, the
    remedy solves -- each an INFO record of the synthesis core (before: silent for minutes)."""
    model, Be, C, gmin = uncontrollable_disturbance_plant(a1=2.0, a2=1.0)
    with caplog.at_level(logging.INFO, logger="lpv_sysid.synthesis"):
        with pytest.raises(SolverError):
            synthesize_hinf(model, None, C, HinfOptions(gamma=0.8 * gmin), Be=Be)
    msgs = [
        r.getMessage() for r in caplog.records if r.name == "lpv_sysid.synthesis.hinf.synthesize"
    ]
    assert any(
        m.startswith("Lemma 1 (seed 0 Eq. 30): building the LMI over 2 systems") for m in msgs
    )
    solving = [m for m in msgs if m.startswith("Lemma 1: solving with")]
    assert len(solving) >= 2 and "scalar variables" in solving[0]  # the first solve + gamma_min
    assert any("quantifying the remedies" in m for m in msgs)
    got = [m for m in msgs if m.startswith("remedies: gamma_min")]
    assert got and f"{gmin:.3g}"[:3] in got[0]
