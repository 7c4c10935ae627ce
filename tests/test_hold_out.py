"""A later stretch of one record held out, as a lab judges a model: the split is forward in
time, exact (the parts put together are the record), refuses parts too short to use, and
survives the record being read again with a model's conventions."""

import numpy as np
import pytest

from lpvpc import hold_out, identify, load_identification_data
from lpvpc.errors import DataError
from lpvpc.io.trial import Trial, write_trial_csv
from lpvpc.simulation.simulate import simulate_pair


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hold")
    sim = simulate_pair("multilevel", seed=2, duration=80.0)  # 1 kHz
    late = lambda t: Trial(t.time, t.position, np.r_[t.torque[0], t.torque[:-1]], dict(t.channels), t.name)  # noqa: E731
    write_trial_csv(late(sim.pt), folder / "PT.csv")
    write_trial_csv(late(sim.ut), folder / "UT.csv")
    return {"pt": folder / "PT.csv", "ut": folder / "UT.csv"}


def test_the_parts_are_the_record_split_forward_in_time(record):
    data = load_identification_data(**record)
    ident, held = hold_out(data, 0.25)
    assert (ident.n, held.n) == (6000, 2000)
    for name in ("position", "torque", "scheduling"):
        assert np.array_equal(np.r_[getattr(ident, name), getattr(held, name)], getattr(data, name))
    q = data.decimation
    assert np.array_equal(np.r_[ident.high_rate.position, held.high_rate.position], data.high_rate.position)
    assert ident.high_rate.n == ident.n * q
    assert held.meta["part"] == {"which": "held-out", "start_s": 60.0, "stop_s": 80.0, "record_s": 80.0}
    first, middle = hold_out(data, (30.0, 50.0))
    assert (first.n, middle.n) == (3000, 2000) and np.array_equal(middle.torque, data.torque[3000:5000])


@pytest.mark.parametrize("heldout, words", [(0.0, "between 0 and 1"), (1.5, "between 0 and 1"),
                                            (0.95, "identification part 4.0 s"), (0.05, "held-out part 4.0 s"),
                                            ((70.0, 90.0), "does not lie inside"), ((1.0, 2.0, 3.0), "(start, stop)")])
def test_a_split_that_leaves_too_little_is_refused(record, heldout, words):
    with pytest.raises(DataError, match=words.replace("(", r"\(").replace(")", r"\)")):
        hold_out(load_identification_data(**record), heldout)


def test_the_parts_are_read_again_as_parts(record):
    """identify lines the late torque channel up by reading its part again from the files:
    the same stretch, lined up; the held-out part is read with the model's skew the same way."""
    ident, held = hold_out(load_identification_data(**record), 0.3)
    model = identify(ident, structure="fixed")
    skew = model.conventions.get("channel_skew_s", 0.0)
    assert skew > 0, "the 1 ms late torque channel was not found"
    again = ident.reload(channel_skew=skew)
    assert again.n == ident.n and np.array_equal(again.torque, ident.torque)
    assert not np.array_equal(again.position, ident.position)  # lined up: the position delayed
    aligned_held = held.reload(channel_skew=skew)
    assert aligned_held.meta["part"]["start_s"] == held.meta["part"]["start_s"]
    assert np.array_equal(model.predict(held).total, model.predict(aligned_held).total)
