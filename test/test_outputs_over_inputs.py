"""An ``--out`` that is an input of the same run, or a signal set a certificate refers to,
is refused unless ``--force`` (issue 25 item 10).

Before: ``verify --out gains.yaml`` replaced the gains with the verification record,
``synthesize --models M --out M`` replaced the models, and ``signals --out`` on an existing
design silently replaced the ``signals.npz`` / ``summary.yaml`` the gains' design envelope
was computed from. The check runs in the CLI dispatcher for every command with ``--out``
(:func:`lpv_sysid.io.files.refuse_overwrite`); the signal set refuses to replace itself
(:func:`lpv_sysid.io.files.refuse_existing`).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from lpv_sysid.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_GAINS = ROOT / "msg_samples" / "gains.yaml"


def _run(argv, capsys):
    rc = main(argv)
    cap = capsys.readouterr()
    return rc, cap.err


def test_verify_out_equal_to_the_gains_is_refused(tmp_path, capsys):
    g = tmp_path / "gains.yaml"
    g.write_bytes(SAMPLE_GAINS.read_bytes())
    before = g.read_bytes()
    rc, err = _run(["verify", "--gains", str(g), "--models", str(g), "--out", str(g)], capsys)
    assert rc == 2 and f"--out {g} is the input --gains {g}" in err and "--force" in err
    assert g.read_bytes() == before
    # through another spelling of the same file (a symlink) too
    link = tmp_path / "link.yaml"
    os.symlink(g, link)
    rc, err = _run(["verify", "--gains", str(g), "--models", str(g), "--out", str(link)], capsys)
    assert rc == 2 and "is the input --gains" in err and g.read_bytes() == before


def test_synthesize_out_equal_to_the_models_is_refused(tmp_path, capsys):
    m = tmp_path / "vertex_models.yaml"
    m.write_text("format: lpv_sysid/vertex_models@1\n")
    cfg = tmp_path / "synthesis.yaml"
    cfg.write_text("hinf: {gamma: 1.0}\n")
    rc, err = _run(
        ["synthesize", "--models", str(m), "--config", str(cfg), "--out", str(m)], capsys
    )
    assert rc == 2 and f"--out {m} is the input --models {m}" in err
    assert m.read_text() == "format: lpv_sysid/vertex_models@1\n"


def test_signals_out_does_not_replace_an_existing_signal_set(tmp_path, capsys):
    cfg = str(ROOT / "config" / "signals_phase2.yaml")
    out = tmp_path / "signals"
    assert _run(["signals", "--config", cfg, "--out", str(out), "--no-plot"], capsys)[0] == 0
    npz = (out / "signals.npz").read_bytes()
    (out / "summary.yaml").write_text((out / "summary.yaml").read_text() + "# mine\n")
    rc, err = _run(["signals", "--config", cfg, "--out", str(out), "--no-plot"], capsys)
    assert rc == 2 and "signals.npz" in err and "exist(s) already" in err and "--force" in err
    assert (out / "summary.yaml").read_text().endswith("# mine\n")
    assert (out / "signals.npz").read_bytes() == npz
    rc, _ = _run(["signals", "--config", cfg, "--out", str(out), "--no-plot", "--force"], capsys)
    assert rc == 0 and not (out / "summary.yaml").read_text().endswith("# mine\n")


@pytest.mark.parametrize("command", [["verify"], ["simulate", "phase2"], ["fly", "phase1"]])
def test_every_command_with_out_has_force(command, capsys):
    with pytest.raises(SystemExit):
        main(command + ["--help"])
    assert "--force" in capsys.readouterr().out


def test_verify_out_equal_to_the_sidecar_a_certificate_refers_to_is_refused(tmp_path, capsys):
    g = tmp_path / "gains.yaml"
    g.write_bytes(SAMPLE_GAINS.read_bytes())
    side = tmp_path / "gains.cert.npz"
    side.write_bytes((SAMPLE_GAINS.parent / "gains.cert.npz").read_bytes())
    before = side.read_bytes()
    rc, err = _run(["verify", "--gains", str(g), "--models", str(g), "--out", str(side)], capsys)
    assert rc == 2 and "(sidecar of --gains" in err and side.read_bytes() == before


def test_referenced_files_finds_a_sidecar_key_spelled_with_an_escape(tmp_path):
    """The text pre-check of referenced_files (no ``sidecar``, no backslash: not parsed) keeps
    every gains file: a key written ``"\\x73idecar"`` still names the sidecar; a file without
    the entry (a models file) refers to nothing."""
    from lpv_sysid.io.formats import referenced_files

    text = SAMPLE_GAINS.read_text()
    assert text.count("  sidecar:") == 1
    g = tmp_path / "gains.yaml"
    g.write_text(text.replace("  sidecar:", '  "\\x73idecar":'))
    assert "sidecar" not in g.read_text()  # only the escape spells it
    assert referenced_files(g) == [tmp_path / "gains.cert.npz"]
    plain = tmp_path / "plain.yaml"
    plain.write_text("certificate: {other: {file: x.npz}}\n")
    assert referenced_files(plain) == []
