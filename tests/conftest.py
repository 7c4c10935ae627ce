"""Shared fixtures: one virtual-subject data set and one identified model per session.

Data reach the identification through the same loaders a user's files would: the
simulated trials are written as CSV and read back with lpvpc.io.
"""

import matplotlib

matplotlib.use("Agg")

import pytest  # noqa: E402

from lpvpc.io import load_identification_data, pair_trials, write_trial_csv  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.simulation.simulate import simulate_pair  # noqa: E402


def _write_and_load(pair, folder, stem):
    pt, ut = folder / f"{stem}_PT.csv", folder / f"{stem}_UT.csv"
    write_trial_csv(pair.pt, pt)
    write_trial_csv(pair.ut, ut)
    return load_identification_data(pt=pt, ut=ut)


@pytest.fixture(scope="session")
def subject(tmp_path_factory):
    """Identification and novel held-out pairs of the virtual subject (seed 0), loaded
    from CSV at 1 kHz and decimated to 100 Hz, with their noise-free counterparts."""
    folder = tmp_path_factory.mktemp("subject")
    ident = simulate_pair("multilevel", seed=0)
    novel = simulate_pair("novel", seed=1)
    return {
        "ident_pair": ident,
        "novel_pair": novel,
        "ident": _write_and_load(ident, folder, "ident"),
        "novel": _write_and_load(novel, folder, "novel"),
        "ident_clean": pair_trials(ident.pt_clean, ident.ut_clean),
        "novel_clean": pair_trials(novel.pt_clean, novel.ut_clean),
        "folder": folder,
    }


@pytest.fixture(scope="session")
def model(subject):
    """The model identified at default settings from the session's identification data."""
    return identify(subject["ident"])


@pytest.fixture(scope="session")
def model_file(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "model.json"
    model.save(path)
    return path
