"""Every count and step is bounded before anything is allocated (issue 25 item 11).

Before: a signals.npz with a 2e-9 s sample interval made ``simulate phase2`` allocate a
~1e9-sample grid (14 GB in 60 s); ``verify --random 1e9``, ``coverage --airframes 1e9`` and
``vrft --runs 1e9`` ran until killed; ``synthesize --gamma 0`` ran on in SCS, ``--gamma
inf/nan`` ended in an allocation error of the solver. Each is now a one-line ConfigError
(exit 2) naming the value and its range, raised by the core before the work starts.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lpv_sysid.errors import ConfigError
from lpv_sysid.signals.store import load_npz, save_npz, validate_table
from lpv_sysid.studies.coverage import CoverageConfig
from lpv_sysid.synthesis.hinf import HinfOptions
from lpv_sysid.synthesis.verify import checker
from lpv_sysid.vrft import examples


def test_signal_sample_interval_below_the_design_limit_is_refused(tmp_path):
    t = np.arange(1000) * 2e-9
    u = np.zeros((1000, 1))
    with pytest.raises(ConfigError, match=r"sample interval 2e-09 s is below 0.0001 s"):
        validate_table(t, u, ["u_ref"], "s.npz")
    # the file path (simulate phase2, the excitation node) meets the same check
    p = tmp_path / "s.npz"
    np.savez(p, t=t, u=u, names=np.array(["u_ref"]))
    with pytest.raises(ConfigError, match="sample interval"):
        load_npz(str(p))
    # 10 kHz, the designer's limit, is fine
    t_ok = np.arange(1000) * 1e-4
    validate_table(t_ok, u, ["u_ref"])
    save_npz(str(tmp_path / "ok.npz"), t_ok, u, ["u_ref"])


@pytest.mark.parametrize(
    "n_random, seed, full_box, flag",
    [
        (10**9, 0, 0, "--random"),
        (-1, 0, 0, "--random"),
        (5, -1, 0, "--seed"),
        (5, 2**40, 0, "--seed"),
        (5, 0, 10**9, "--full-box"),
    ],
)
def test_verify_counts_are_bounded(n_random, seed, full_box, flag):
    with pytest.raises(ConfigError, match=f"{flag} .*must be an integer in 0 .. "):
        checker.verify_files("missing.yaml", "missing.yaml", n_random, seed, full_box=full_box)


def test_coverage_and_vrft_counts_are_bounded():
    with pytest.raises(
        ConfigError, match=r"coverage.airframes: 1000000000 exceeds the limit of 1000"
    ):
        CoverageConfig(airframes=10**9)
    with pytest.raises(ConfigError, match=r"runs 1000000000: need 2 .. 10000"):
        examples.lv100_statistics(1000, 10**9)
    with pytest.raises(ConfigError, match=r"--n 100000000000: the examples take 50 .. "):
        examples.lv100_statistics(10**11, 3)


@pytest.mark.parametrize("gamma", [0.0, 1e-12, math.inf, math.nan, -1.0, 1e300])
def test_synthesis_gamma_is_bounded_on_every_path(gamma, tmp_path):
    from lpv_sysid.synthesis.gains import load_inputs

    with pytest.raises(ConfigError, match="hinf.gamma"):
        HinfOptions.from_dict({"gamma": gamma})
    cfg = tmp_path / "synthesis.yaml"
    cfg.write_text("hinf: {gamma: 1.0}\n")
    with pytest.raises(ConfigError, match="gamma"):  # the --gamma override, before the models
        load_inputs(str(tmp_path / "no_models.yaml"), str(cfg), gamma=gamma)
