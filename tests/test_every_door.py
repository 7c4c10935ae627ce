"""One record through every door gives one answer.

A lab's record as the lab's files hold it: 1 kHz, positions in degrees, the torque with the
opposite sign, and the torque channel recorded a fraction of a sample late. The model is
identified by ``lpvpc identify`` and by the README's Python quick start as written (with the
sign and unit keywords a user adds), a later record is predicted by ``lpvpc predict``, by
``model.predict``, by the FMU through the guide's fmpy recipe and by the CasADi function:
the same model and the same torque, to 1e-9 of the torque's scale.
"""

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from lpvpc import LPVPCModel
from lpvpc.cli import main as cli_main
from lpvpc.io import load_identification_data
from lpvpc.io.trial import Trial, write_trial_csv
from lpvpc.simulation.simulate import simulate_pair

REPO = Path(__file__).resolve().parents[1]
SKEW_S = 0.45e-3  # the torque channel's lag: less than one 1 kHz sample
KEYWORDS = 'torque_sign=-1, position_unit="deg", '
RELATIVE = 1e-9


def lab_trial(trial: Trial) -> Trial:
    """``trial`` (SI, 1 kHz) as the lab's rig writes it: degrees, torque negated, torque late."""
    late = np.interp(trial.time - SKEW_S, trial.time, trial.torque)
    channels = {k: (np.degrees(v) if k in ("command", "scheduling") else v) for k, v in trial.channels.items()}
    return Trial(trial.time, np.degrees(trial.position), -late, channels, trial.name)


@pytest.fixture(scope="module")
def lab_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("door") / "subject"
    folder.mkdir()
    for stem, kind, seed, duration in (("ident", "multilevel", 5, 60.0), ("novel", "novel", 6, 30.0)):
        pair = simulate_pair(kind, seed=seed, duration=duration)
        write_trial_csv(lab_trial(pair.pt), folder / f"{stem}_PT.csv")
        write_trial_csv(lab_trial(pair.ut), folder / f"{stem}_UT.csv")
    return folder


def readme_block() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    return re.search(r"## Quick start: Python\n+```python\n(.*?)```", text, re.S).group(1)


def with_user_keywords(block: str) -> str:
    """The README block with the keywords a user whose files use the lab's conventions adds."""
    out, n = re.subn(r"load_identification_data\(", "load_identification_data(" + KEYWORDS, block)
    assert n == 2, "the README's quick start no longer loads two records"
    return out


def assert_same(a, b, what):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, f"{what}: {a.shape} != {b.shape}"
    scale = float(np.max(np.abs(b)))
    assert float(np.max(np.abs(a - b))) <= RELATIVE * scale, \
        f"{what}: differs by {np.max(np.abs(a - b)):.3g} N m (scale {scale:.3g})"


@pytest.mark.slow
def test_one_record_gives_one_answer_through_every_door(lab_files, tmp_path, monkeypatch):
    ident_pt, ident_ut = lab_files / "ident_PT.csv", lab_files / "ident_UT.csv"
    novel_pt, novel_ut = lab_files / "novel_PT.csv", lab_files / "novel_UT.csv"

    # the command line
    cli_model_path = tmp_path / "cli.json"
    conventions = ["--torque-sign", "-1", "--position-unit", "deg"]
    assert cli_main([*map(str, ["identify", "--pt", ident_pt, "--ut", ident_ut, "-o", cli_model_path]),
                     *conventions, "--quiet"]) == 0
    cli_model = LPVPCModel.load(cli_model_path)
    assert cli_model.conventions["torque_sign"] == -1.0 and cli_model.conventions["position_unit"] == "deg"
    skew = cli_model.conventions["channel_skew_s"]
    assert 0 < skew < 2e-3, f"the late torque channel was found at {skew * 1e3:.2f} ms"
    for causal in (False, True):
        out = tmp_path / f"cli_{causal}.csv"
        argv = ["predict", str(cli_model_path), "--pt", str(novel_pt), "--ut", str(novel_ut), "--out", str(out)]
        assert cli_main(argv + (["--causal"] if causal else []) + ["--quiet"]) == 0  # the model's conventions
        table = np.genfromtxt(out, delimiter=",", names=True)
        if causal:
            cli_causal = table["predicted"]
        else:
            cli_total, cli_measured = table["predicted"], table["measured"]

    # the README's Python quick start, as written, with the keywords a user adds
    monkeypatch.chdir(lab_files.parent)
    namespace = {}
    exec(compile(with_user_keywords(readme_block()), "README.md", "exec"), namespace)
    model, test, pred = namespace["model"], namespace["test"], namespace["pred"]

    # the same model from identify() and from lpvpc identify
    assert model.conventions == cli_model.conventions
    rho = np.linspace(*model.scheduling_range, 9)
    assert np.array_equal(model.elastic_stiffness(rho), cli_model.elastic_stiffness(rho))
    assert model.fit["vaf"] == cli_model.fit["vaf"]
    assert model.to_dict()["fit"]["channel_skew"] == cli_model.to_dict()["fit"]["channel_skew"]

    # the same torque from the command line and from Python
    assert_same(test.torque, cli_measured, "measured torque")
    assert_same(pred.total, cli_total, "model.predict vs lpvpc predict")
    causal = model.predict(test, causal=True).total
    assert_same(causal, cli_causal, "model.predict(causal=True) vs lpvpc predict --causal")
    # a model method that loads the record gives the same
    assert_same(model.predict(model.load_record(pt=novel_pt, ut=novel_ut)).total, pred.total, "load_record")

    # the FMU through the guide's fmpy recipe, on the record read as the model's (model-rate
    # signals: what the FMU sees), equals the offline causal prediction
    record = dataclasses.replace(model.load_record(pt=novel_pt, ut=novel_ut), high_rate=None)
    offline = model.predict(record, causal=True).total
    model.export_fmu(tmp_path / "model.fmu")
    guide = (REPO / "docs" / "guide" / "fmu_casadi.md").read_text(encoding="utf-8")
    recipe = re.search(r"<!-- fmu-recipe -->\n```python\n(.*?)```", guide, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    scope = {"position": record.position, "scheduling": record.scheduling}
    exec(compile(recipe, "fmu_casadi.md", "exec"), scope)
    assert_same(scope["torque"], offline, "FMU (fmpy recipe) vs model.predict(causal=True)")

    # the CasADi function, run as a user with only casadi installed would
    import casadi

    from lpvpc.export import replay_inputs

    model.export_casadi(tmp_path / "model.casadi", variant="causal")
    step = casadi.Function.load(str(tmp_path / "model.casadi"))
    rows = replay_inputs(model, record.position, record.scheduling, variant="causal")
    out = step.mapaccum(record.n)(state=np.zeros(step.size1_in("state")), **rows)
    assert_same(np.asarray(out["torque"]).ravel(), offline, "CasADi vs model.predict(causal=True)")


def test_a_record_read_with_another_sign_is_refused_naming_both(lab_files):
    """Data loaded with a torque sign other than the model's: one error naming both."""
    from lpvpc.errors import DataError
    from lpvpc.identification.identify import identify

    files = dict(pt=lab_files / "novel_PT.csv", ut=lab_files / "novel_UT.csv")
    model = identify(load_identification_data(**files, torque_sign=-1, position_unit="deg"), structure="fixed")
    with pytest.raises(DataError, match=r"torque sign: the record was read with 1\.0, the model's record with -1\.0"):
        model.predict(load_identification_data(**files, position_unit="deg"))
    with pytest.raises(DataError, match="torque sign"):
        model.load_record(**files, torque_sign=1)
    assert json.loads(json.dumps(model.record_conventions()))["torque_sign"] == -1.0
