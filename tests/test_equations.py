"""The shared model equations: record edges."""

import numpy as np

from lpvpc import equations as eq

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
