"""The rectifier's knee as the record's regressors round it (lpvpc.models.reflex_uncertainty.knee_rounding).

A Chebyshev order-4 velocity basis on the 1 kHz path cannot hold the rectifier's knee: read
off the fitted curve, a low threshold comes out high with a high gain and a high threshold
with a low gain. The population's threshold falls toward dorsiflexion, so the gain slope was
read 1.1-1.4 times the truth's. On noise-free records (the noise's part taken out) of three
population subjects whose threshold falls steeply, the plain reading's slope is 1.23-1.27
times the truth's and the mapped-back one 0.94-1.03; the threshold's mean error 0.18-0.28
rad/s plain and 0.02-0.04 mapped back.
"""

import json
import warnings

import numpy as np
import pytest

import lpvpc
from lpvpc.errors import ModelFileError
from lpvpc.models.model import LPVPCModel
from lpvpc.simulation.population import draw_subject, simulate_subject


def _identified(seed, form):
    s = draw_subject(seed, stiffness=form)
    pair = simulate_subject(s, snr_db=np.inf, duration=60.0)  # noise-free: the reading's bias alone
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = lpvpc.identify(lpvpc.pair_trials(pair.pt, pair.ut), high_rate_reflex=True,
                               high_rate_velocity_basis="chebyshev", high_rate_velocity_order=4)
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 9)
    return s.params, model, rho


@pytest.fixture(scope="module", params=[(115, "polynomial"), (183, "polynomial")], ids=["seed115", "seed183"])
def identified(request):
    return _identified(*request.param)


def test_the_gain_slope_and_threshold_are_read_through_the_knee_rounding(identified):
    truth, model, rho = identified
    g_true, t_true = truth.reflex_gain(rho), truth.reflex_threshold(rho)

    def slope_ratio(g):
        return np.polyfit(rho, g, 1)[0] / np.polyfit(rho, g_true, 1)[0]

    g_plain, t_plain = model.reflex_gain_threshold(rho, knee_corrected=False)
    g, t = model.reflex_gain_threshold(rho)
    assert slope_ratio(g_plain) > 1.15  # the rounding's bias: what the population benchmark saw
    assert abs(slope_ratio(g) - 1.0) < 0.1, slope_ratio(g)
    assert np.mean(np.abs(t_plain - t_true)) > 0.15
    assert np.mean(np.abs(t - t_true)) < 0.06, t - t_true
    (g_lo, g_hi), (t_lo, t_hi) = model.reflex_gain_interval(rho), model.reflex_threshold_interval(rho)
    assert np.all((g_lo <= g) & (g <= g_hi)) and np.all((t_lo <= t) & (t <= t_hi))  # the estimate inside
    assert np.all((g_lo <= g_true) & (g_true <= g_hi)) and np.all((t_lo <= t_true) & (t_true <= t_hi))


def test_the_knee_rounding_is_stored_and_checked(tmp_path):
    truth, model, rho = _identified(183, "polynomial")
    kr = model.uncertainty["knee_rounding"]
    r, t_fit = np.asarray(kr["gain_factor"]), np.asarray(kr["fitted_threshold"])
    assert r[0] > 1.05 and r[-1] < 0.95  # low knees' gains read high, high knees' low
    assert t_fit[0] > 0.1  # a true threshold of 0 is read well above it
    path = tmp_path / "m.json"
    model.save(path)
    loaded = LPVPCModel.load(path)
    assert np.array_equal(np.array(loaded.reflex_gain_threshold(rho)), np.array(model.reflex_gain_threshold(rho)))
    d = json.loads(path.read_text())
    d["uncertainty"]["knee_rounding"]["gain_factor"].pop()
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match=r"uncertainty.knee_rounding.gain_factor has shape"):
        LPVPCModel.load(path)


def test_model_rate_records_store_no_knee_rounding():
    """100 Hz files: no high-rate velocity to measure the rounding with; the reading stands."""
    s = draw_subject(183, stiffness="polynomial")
    pair = simulate_subject(s, snr_db=np.inf, duration=30.0, fs_out=100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = lpvpc.identify(lpvpc.pair_trials(pair.pt, pair.ut), structure="fixed")
    rho = np.array([-0.2, 0.0])
    assert "knee_rounding" not in model.uncertainty
    assert np.array_equal(np.array(model.reflex_gain_threshold(rho)),
                          np.array(model.reflex_gain_threshold(rho, knee_corrected=False)))
