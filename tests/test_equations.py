"""The shared model equations: record edges."""

import numpy as np
import pytest

from lpvpc.models import equations as eq

FS = 100.0


def test_record_ending_mid_perturbation_is_held_not_dropped_to_zero():
    pos = np.r_[np.zeros(20), np.full(30, 0.04)]  # a step, still held when the record ends
    assert np.allclose(eq.velocity(pos, FS)[-2:], 0.0) and np.allclose(eq.acceleration(pos, FS)[-2:], 0.0)
    future = eq.lagged(pos, [-3, -1, 0, 2])
    assert np.allclose(future[-3:, 0], 0.04) and np.allclose(future[-1:, 1], 0.04)
    assert np.allclose(future[:, 2], pos)
    assert np.allclose(future[:2, 3], 0.0) and np.allclose(future[2:, 3], pos[:-2])  # zero before the start


def test_held_end_removes_the_spurious_step_from_the_two_sided_prediction(model, subject):
    """The novel record ends mid-perturbation: the last samples' prediction error stays at
    the level of the rest of the record (a zero after the end put a 10 N m error there)."""
    d = subject["novel"]
    err = d.torque - model.predict(d.position, d.scheduling, warn=False).total
    assert abs(d.position[-1]) > 0.005
    assert np.max(np.abs(err[-4:])) < 4 * np.std(err)


def test_five_point_derivatives_are_exact_for_quartics_inside_the_record():
    fs = 100.0
    t = np.arange(40) / fs
    p = 0.3 * t**4 - 0.2 * t**3 + t**2 - 0.5 * t
    v, a = eq.derivatives(p, fs, "central5")
    inner = slice(2, -2)
    np.testing.assert_allclose(v[inner], (1.2 * t**3 - 0.6 * t**2 + 2 * t - 0.5)[inner], rtol=0, atol=1e-9)
    np.testing.assert_allclose(a[inner], (3.6 * t**2 - 1.2 * t + 2)[inner], rtol=0, atol=1e-7)
    v3, a3 = eq.derivatives(p, fs, "central3")
    assert np.array_equal(v3, eq.velocity(p, fs)) and np.array_equal(a3, eq.acceleration(p, fs))
    with pytest.raises(ValueError, match="unknown derivative stencil"):
        eq.derivatives(p, fs, "spline")
