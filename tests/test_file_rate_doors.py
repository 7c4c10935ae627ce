"""A model whose reflex runs on the file's own rate (``high_rate_reflex``, 1 kHz files
identified at 100 Hz) gives one held-out answer through every door: ``model.predict(data)``,
the validation harness's headline and the diagnosis's model VAF. The FMU and CasADi compute
the reflex on the model-rate velocity; the harness reports that route beside the headline."""

import warnings

import numpy as np
import pytest

import lpvpc
from lpvpc.cli import main
from lpvpc.diagnosis.diagnose import diagnose
from lpvpc.identification.identify import identify
from lpvpc.io import load_identification_data
from lpvpc.models.model import vaf
from lpvpc.validation import validate


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    folder = tmp_path_factory.mktemp("file_rate")
    assert main(["-q", "simulate", "--out", str(folder / "sim"), "--duration", "80"]) == 0
    pt, ut = folder / "sim" / "ident_PT.csv", folder / "sim" / "ident_UT.csv"
    ident, held = lpvpc.hold_out(load_identification_data(pt=pt, ut=ut), 0.3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = identify(ident, structure="fixed", high_rate_reflex=True)
    file_rate = model.predict(held, warn=False).total
    model_rate = model.predict(held.position, held.scheduling, warn=False).total
    return {"folder": folder, "pt": pt, "ut": ut, "model": model, "held": held,
            "vaf": vaf(held.torque, file_rate), "vaf_model_rate": vaf(held.torque, model_rate)}


def test_the_two_reflex_rates_differ_on_this_record(case):
    """The premise: otherwise the doors below could not disagree."""
    assert case["model"].high_rate is not None
    assert abs(case["vaf"] - case["vaf_model_rate"]) > 1e-4


def test_validate_headline_is_the_identified_model(case):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = validate(case["model"], case["pt"], case["ut"], case["folder"] / "report", hold_out=0.3,
                       measure_load_effect=False, write_report=False)
    m = res.metrics
    assert m["vaf"] == pytest.approx(case["vaf"], abs=1e-9)
    assert m["routes"]["numpy_model_rate"]["vaf"] == pytest.approx(case["vaf_model_rate"], abs=1e-9)
    assert "1000 Hz velocity" in m["routes"]["numpy"]["description"]
    assert m["route_agreement"]["pass"], m["route_agreement"]  # the FMU still matches what it computes


def test_diagnose_scores_the_identified_model(case):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = diagnose(case["model"], case["held"])
    assert d.vaf == pytest.approx(case["vaf"], abs=1e-9)
