"""Config loading (named bad keys) and the `lpv-sysid signals` command (files written,
exit 2 on bad input)."""

import os

import numpy as np
import pytest
import yaml

from lpv_sysid.cli.main import main
from lpv_sysid.errors import ConfigError
from lpv_sysid.signals.multisine import PHASE1_DEFAULT, SignalsConfig, load_config
from lpv_sysid.signals.store import load_npz

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SMALL = {
    "duration": 20.0,
    "sample_rate": 20.0,
    "groups": [
        {"name": "reference", "channels": ["u_d", "v_d", "w_d"], "band": [0.05, 0.5], "peak": 5.0},
        {
            "name": "excitation",
            "channels": ["ue_t", "ue_a", "ue_e", "ue_r"],
            "band": [0.5, 4.0],
            "energy": 1.0,
        },
    ],
    "optimisation": {"max_iter": 30, "clip_iter": 10, "restarts": 0},
    "weights": {
        "group": "excitation",
        "excitation_magnitudes": [0.1, 0.2, 0.3, 0.4],
        "velocity_magnitudes": [1.0, 1.0, 2.0],
    },
}


def _write(tmp_path, data, name="cfg.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return str(p)


def test_cli_writes_npz_summary_and_png(tmp_path, capsys):
    cfg = _write(tmp_path, SMALL)
    out = tmp_path / "out"
    assert main(["signals", "--config", cfg, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    for f in ("signals.npz", "summary.yaml", "signals.png"):
        assert (out / f).is_file()
        assert f"wrote {out / f}" in printed
    t, u, names = load_npz(str(out / "signals.npz"))
    assert t.shape == (400,) and u.shape == (400, 7)
    assert names == ("u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r")
    with np.load(out / "signals.npz") as z:
        assert set(z.files) == {"t", "u", "names"}
    s = yaml.safe_load((out / "summary.yaml").read_text())
    ch = {c["name"]: c for c in s["channels"]}
    assert ch["u_d"]["harmonics"] == list(range(1, 11, 3)) and ch["u_d"]["band_hz"] == [0.05, 0.5]
    assert ch["ue_t"]["harmonics"] == list(range(11, 81, 4))
    # the summary's RPF is the RPF of the written samples
    j = names.index("ue_a")
    x = u[:, j]
    assert ch["ue_a"]["rpf"] == pytest.approx(
        (x.max() - x.min()) / (2 * np.sqrt(2) * np.sqrt(np.mean(x * x)))
    )
    assert ch["ue_a"]["rpf"] < ch["ue_a"]["rpf_schroeder"]
    c = np.array(s["correlation"]["matrix"])
    assert (
        c.shape == (7, 7)
        and np.allclose(np.diag(c), 1.0)
        and s["correlation"]["max_abs_offdiagonal"] < 1e-9
    )
    assert np.allclose(s["R"], np.sqrt(4 * 20 / 2) * np.diag([0.1, 0.2, 0.3, 0.4]))
    assert np.allclose(s["Q"], np.sqrt(3 * 20) * np.diag([1.0, 1.0, 2.0]))
    assert (out / "signals.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_help_lists_signals(capsys):
    with pytest.raises(SystemExit) as e:
        main(["signals", "--help"])
    assert e.value.code == 0
    assert "--config" in capsys.readouterr().out


@pytest.mark.parametrize(
    "bad, needle",
    [
        ({**SMALL, "durration": 3}, "durration"),
        ({**SMALL, "groups": [{**SMALL["groups"][0], "chanels": ["a"]}]}, "chanels"),
        ({**SMALL, "sample_rate": "fast"}, "sample_rate"),
        ({**SMALL, "groups": [{**SMALL["groups"][0], "band": [0.5, 0.1]}]}, "band"),
        ({**SMALL, "groups": [{**SMALL["groups"][0], "band": [0.1, 12.0]}]}, "Nyquist"),
        (
            {**SMALL, "groups": [{**SMALL["groups"][0], "peak": 1.0, "energy": 1.0}]},
            "either 'peak' or 'energy'",
        ),
        (
            {**SMALL, "groups": [{**SMALL["groups"][0], "power_fraction": [0.5, 0.5, 0.0]}]},
            "power_fraction",
        ),
        (
            {**SMALL, "weights": {"group": "reference", "excitation_magnitudes": [1, 1, 1]}},
            "energy: 1.0",
        ),
        (
            {**SMALL, "weights": {**SMALL["weights"], "velocity_magnitudes": [1, 2]}},
            "velocity_magnitudes",
        ),
        ({**SMALL, "optimisation": {"max_iter": -1}}, "max_iter"),
        (
            {**SMALL, "groups": [SMALL["groups"][0], {**SMALL["groups"][1], "channels": ["u_d"]}]},
            "more than once",
        ),
        ({**SMALL, "duration": 10.01}, "integer"),
        (
            {
                **SMALL,
                "groups": [{**SMALL["groups"][0], "band": [0.05, 0.06]}, SMALL["groups"][1]],
            },
            "free harmonics",
        ),
        ({**SMALL, "groups": [SMALL["groups"][0]]}, "no group named 'excitation'"),
    ],
)
def test_cli_bad_config_exit_2_names_problem(tmp_path, capsys, bad, needle):
    cfg = _write(tmp_path, bad)
    assert main(["signals", "--config", cfg, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o" / "signals.npz").exists()


def test_cli_malformed_and_missing_file(tmp_path, capsys):
    cfg = _write(tmp_path, "duration: [1, 2\n")
    assert main(["signals", "--config", cfg, "--out", str(tmp_path / "o")]) == 2
    assert "malformed YAML" in capsys.readouterr().err
    assert (
        main(["signals", "--config", str(tmp_path / "none.yaml"), "--out", str(tmp_path / "o")])
        == 2
    )
    assert "no such file" in capsys.readouterr().err


def test_shipped_configs_load():
    c2 = load_config(os.path.join(ROOT, "config", "signals_phase2.yaml"))
    assert c2.channel_names == ("u_d", "v_d", "w_d", "ue_t", "ue_a", "ue_e", "ue_r")
    assert c2.duration == 100.0 and c2.sample_rate == 50.0
    assert c2.groups[0].band == (0.01, 0.2) and c2.groups[1].band == (0.51, 5.0)
    assert c2.groups[0].peak == (4.5, 4.5, 4.5) and c2.groups[1].energy == 1.0
    c1 = load_config(os.path.join(ROOT, "config", "signals_phase1.yaml"))
    assert c1 == SignalsConfig.from_dict(PHASE1_DEFAULT)
    assert c1.duration == 30.0 and c1.groups[0].band == (0.2, 2.0) and len(c1.channel_names) == 4


def test_from_dict_rejects_non_mapping():
    with pytest.raises(ConfigError, match="mapping"):
        SignalsConfig.from_dict([1, 2])


def test_load_npz_rejects_bad_files(tmp_path):
    p = tmp_path / "a.npz"
    np.savez(p, t=np.arange(3.0), u=np.zeros((3, 1)))
    with pytest.raises(ConfigError, match="missing array"):
        load_npz(str(p))
    q = tmp_path / "b.npz"
    q.write_bytes(b"not a zip file")
    with pytest.raises(ConfigError, match="not a readable"):
        load_npz(str(q))
    r = tmp_path / "c.npz"
    np.savez(r, t=np.arange(3.0), u=np.zeros((4, 1)), names=np.array(["x"]))
    with pytest.raises(ConfigError, match="'u' must be"):
        load_npz(str(r))
