"""The report's multisine spectra (issue 23 item 3): the harmonic count and x range of each
panel come from the harmonics (given, or read from the spectrum when a ``fly`` run keeps no
``summary.yaml``), on records of one or several periods."""

from __future__ import annotations

import numpy as np
import pytest

from lpv_sysid.report import plots


@pytest.fixture
def figures(monkeypatch):
    got = []

    def keep(fig, path):
        got.append(fig)
        return path

    monkeypatch.setattr(plots, "_save", keep)
    return got


def _multisine(periods: int, harmonics, f0=0.2, fs=50.0):
    t = np.arange(int(round(periods / f0 * fs))) / fs
    u = sum(0.3 * np.cos(2 * np.pi * k * f0 * t + 0.7 * k) for k in harmonics)
    return t, np.column_stack([u + 1.5, 0.5 * u])  # a vertex offset on the first channel


@pytest.mark.parametrize("periods", [1, 3])
def test_harmonics_read_from_the_spectrum_and_x_range(figures, tmp_path, periods):
    h = [2, 3, 5, 7, 11]
    t, u = _multisine(periods, h)
    plots.plot_spectra(t, u, ["u_ref", "v_ref"], [None, None], 0.2, tmp_path / "s.png")
    fig = figures[-1]
    ax = fig.axes[0]
    assert ax.get_title() == "u_ref: 5 harmonics (read from the spectrum)"
    assert ax.get_xlim()[1] == pytest.approx(1.25 * 11 * 0.2)  # not the 25 Hz Nyquist
    dots = ax.lines[0].get_xdata()
    np.testing.assert_allclose(dots, np.array(h) * 0.2)


def test_given_harmonics_on_a_record_of_three_periods(figures, tmp_path):
    h = [1, 4, 6]
    t, u = _multisine(3, h)
    plots.plot_spectra(t, u, ["a", "b"], [h, h], 0.2, tmp_path / "s.png")
    ax = figures[-1].axes[1]
    assert ax.get_title() == "b: 3 harmonics"
    np.testing.assert_allclose(ax.lines[0].get_xdata(), np.array(h) * 0.2)
    np.testing.assert_allclose(ax.lines[0].get_ydata(), 0.5 * 0.3, rtol=1e-9)
