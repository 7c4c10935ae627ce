"""The reflex gain's slope over position (lpvpc.models.reflex_uncertainty.reflex_gain_slope): on the
virtual subject, whose true gain is known, its interval covers the true slope and says the
slope is determined; on a record that hardly excites the reflex it says "not determined"."""

import warnings

import numpy as np
import pytest

from lpvpc.identification.identify import identify
from lpvpc.io import pair_trials
from lpvpc.models.reflex_uncertainty import SLOPE_TOLERANCE, reflex_gain_slope
from lpvpc.simulation.simulate import simulate_pair
from lpvpc.simulation.subject import SubjectParams


def _identified(**kwargs):
    params = SubjectParams()
    sim = simulate_pair("multilevel", params=params, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # short records: range and physiology notes
        return identify(pair_trials(sim.pt, sim.ut)), params


def _true_slope(params, rho):
    """The least-squares line of the true gain over the same positions (N m s/rad per rad)."""
    return float(np.polyfit(rho, params.reflex_gain(rho), 1)[0])


@pytest.fixture(scope="module")
def normal():
    """A quiet 60-s record of the virtual subject (40 dB) from 1 kHz files, identify at its defaults."""
    return _identified(seed=1, duration=60.0, snr_db=40.0)


@pytest.fixture(scope="module")
def weak():
    """A 30-s record with perturbations of +-0.01 rad: little stretch velocity, little reflex (the
    nonlinearity is left on the model-rate velocity)."""
    return _identified(seed=2, duration=30.0, perturbation_amplitude=0.01)


def test_the_slope_is_the_line_of_the_reported_gains(normal):
    model, _ = normal
    out = reflex_gain_slope(model)
    lo, hi = model.scheduling_range
    assert out["rho"][0] > lo and out["rho"][-1] < hi  # the central part of the range
    line = np.polyfit(out["rho"], model.reflex_gain_threshold(out["rho"])[0], 1)[0]
    assert out["slope"] == pytest.approx(line, rel=1e-9)
    assert out["lower"] <= out["slope"] <= out["upper"]


def test_interval_covers_the_true_slope_and_says_determined(normal):
    model, params = normal
    out = reflex_gain_slope(model)
    truth = _true_slope(params, out["rho"])
    assert out["lower"] <= truth <= out["upper"], (out, truth)
    assert out["determined"], out
    # determined means every slope of the interval is within the tolerance: so is the truth
    assert abs(out["slope"] / truth - 1.0) <= SLOPE_TOLERANCE


def test_determined_only_when_the_interval_is_within_the_tolerance(normal, weak):
    for model, _ in (normal, weak):
        out = reflex_gain_slope(model)
        s, lo, hi = out["slope"], out["lower"], out["upper"]
        within = lo * hi > 0 and min(abs(lo), abs(hi)) >= abs(s) / (1 + SLOPE_TOLERANCE) \
            and max(abs(lo), abs(hi)) <= abs(s) / (1 - SLOPE_TOLERANCE)
        assert out["determined"] == within
        assert not reflex_gain_slope(model, tolerance=1e-3)["determined"]  # no 95 % interval is that narrow


def test_little_reflex_excitation_is_not_determined(weak):
    model, params = weak
    out = reflex_gain_slope(model)
    assert not out["determined"], out
    truth = _true_slope(params, out["rho"])
    assert out["lower"] <= truth <= out["upper"], (out, truth)  # wide, and still honest


def test_the_summary_prints_the_slope_and_says_when_its_size_is_not_determined(normal, weak):
    """What `lpvpc identify` and ``model.summary()`` print: the library's slope and interval,
    and "not determined" exactly when the library says so."""
    from lpvpc.models.summary import physiology_lines
    from lpvpc.models.uncertainty import NOT_DETERMINED

    for model, _ in (normal, weak):
        sl = reflex_gain_slope(model)
        line = [ln for ln in physiology_lines(model) if ln.startswith("gain slope:")]
        assert len(line) == 1, physiology_lines(model)
        assert f"{sl['slope']:+.1f} N m s/rad per rad" in line[0]
        assert f"{sl['lower']:+.1f}..{sl['upper']:+.1f}" in line[0]
        assert (NOT_DETERMINED in line[0]) == (not sl["determined"])
        assert line[0] in str(model.summary())


def test_the_reports_physiology_table_carries_the_slope(normal):
    """The validation, diagnosis and improve reports open with the physiology table; the slope
    line `lpvpc identify` prints sits under it."""
    from html import escape

    from lpvpc.models.summary import gain_slope_lines, physiology_table_html
    from lpvpc.validation.report import _physiology_parts

    model, _ = normal
    text = escape(gain_slope_lines(model)[0].split(":", 1)[1].strip())
    assert f"Reflex gain slope: {text}" in physiology_table_html(model)
    assert f"Reflex gain slope: {text}" in _physiology_parts(model)[0]
