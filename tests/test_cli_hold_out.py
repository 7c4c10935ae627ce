"""``--hold-out FRACTION | START:STOP``: one record, its later stretch kept out of
identification and used as the held-out record by identify, validate, diagnose and improve,
split as ``lpvpc.hold_out`` splits it in Python; the stretch recorded in the model file; bad
values refused with one line."""

import json

import pytest

import lpvpc
from lpvpc.cli import main
from lpvpc.identification.identify import identify
from lpvpc.io import load_identification_data
from lpvpc.models.model import LPVPCModel, vaf

DURATION = 80.0  # s: a held-out 30 % of 24 s, long enough for a diagnosis (20 s)


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    """A virtual-subject record written by ``lpvpc simulate`` (1 kHz CSV), a model identified
    with ``--hold-out 0.3`` and the same split and model in Python."""
    folder = tmp_path_factory.mktemp("hold_out")
    assert main(["-q", "simulate", "--out", str(folder / "sim"), "--duration", str(DURATION)]) == 0
    pt, ut = folder / "sim" / "ident_PT.csv", folder / "sim" / "ident_UT.csv"
    model_file = folder / "model.json"
    assert main(["-q", "identify", "--pt", str(pt), "--ut", str(ut), "--hold-out", "0.3", "--structure", "fixed",
                 "-o", str(model_file)]) == 0
    data = load_identification_data(pt=pt, ut=ut)
    ident, held = lpvpc.hold_out(data, 0.3)
    model = identify(ident, structure="fixed")
    return {"folder": folder, "pt": pt, "ut": ut, "model_file": model_file, "ident": ident, "held": held,
            "model": model, "vaf": vaf(held.torque, model.predict(held, warn=False).total)}


def _cli(argv, capsys):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def test_identify_holds_out_the_later_part_as_python_does(record, capsys):
    saved = LPVPCModel.load(record["model_file"])
    h = saved.fit["hold_out"]
    held, ident = record["held"], record["ident"]
    assert h["value"] == 0.3 and h["held_out_s"] == [held.meta["part"]["start_s"], held.meta["part"]["stop_s"]]
    assert h["identification_s"] == [0.0, 56.0] and h["held_out_s"] == [56.0, 80.0] and h["record_s"] == DURATION
    assert h["files"] == [str(record["pt"].resolve()), str(record["ut"].resolve())]
    # the same model (fitted to the same earlier part) and the same held-out VAF as the Python path
    assert saved.fit["vaf"] == pytest.approx(record["model"].fit["vaf"], abs=1e-9)
    assert h["vaf"] == pytest.approx(record["vaf"], abs=1e-9)
    assert 80.0 < h["vaf"] < 100.0 and ident.n == 5600 and held.n == 2400
    # and it says so
    status, out, _ = _cli(["-q", "identify", "--pt", record["pt"], "--ut", record["ut"], "--hold-out", "56:",
                           "--structure", "fixed", "-o", record["folder"] / "range.json"], capsys)
    assert status == 0 and f"held out:    56.0..80.0 s of the 80.0 s record (--hold-out 56:): VAF {record['vaf']:.2f} %" in out
    assert LPVPCModel.load(record["folder"] / "range.json").fit["hold_out"]["vaf"] == pytest.approx(record["vaf"], abs=1e-9)


def test_diagnose_takes_the_stretch_the_model_recorded(record, capsys):
    out_json = record["folder"] / "diagnosis.json"
    status, out, err = _cli(["-q", "diagnose", record["model_file"], "--pt", record["pt"], "--ut", record["ut"],
                             "--hold-out", "--json", out_json], capsys)
    assert status == 0, err
    assert "held out:  56.0..80.0 s of the 80.0 s record (--hold-out 0.3)" in out
    d = json.loads(out_json.read_text())
    assert d["n_samples"] == record["held"].n and d["data"].endswith("[5600:8000]")
    assert d["vaf"] == pytest.approx(record["vaf"], abs=1e-3)  # (the file keeps 3 decimals)
    # the earlier stretch is the model's identification record (its data hash): given as the
    # reference, as in Python diagnose(model, held, reference=ident)
    assert "reference: the rest of the record, which the model was identified on" in out
    assert d["settings"]["reference"]
    py = lpvpc.diagnose(record["model"], record["held"], reference=record["ident"])
    assert [c["effect"] for c in d["candidates"]] == [c.effect for c in py.candidates]
    assert d["surrogate_cv_vaf"] == pytest.approx(py.surrogate_vaf, abs=1e-3)
    # a model identified elsewhere: the earlier stretch is not its record, so no reference
    other = record["folder"] / "other.json"
    assert main(["-q", "identify", "--pt", str(record["pt"]), "--ut", str(record["ut"]), "--hold-out", "0.3",
                 "--structure", "fixed", "--irf-length", "0.03", "-o", str(other)]) == 0
    m = LPVPCModel.load(other)
    m.provenance["data_hash"] = "0" * 64
    m.save(other)
    status, out, err = _cli(["-q", "diagnose", other, "--pt", record["pt"], "--ut", record["ut"], "--hold-out"],
                            capsys)
    assert status == 0 and "reference:" not in out, out


def test_validate_on_the_held_out_stretch(record, capsys):
    report = record["folder"] / "report"
    status, out, err = _cli(["-q", "validate", record["model_file"], "--pt", record["pt"], "--ut", record["ut"],
                             "--hold-out", "--report", report], capsys)
    assert status == 0, err
    assert "held out:    56.0..80.0 s of the 80.0 s record (--hold-out 0.3)" in out
    m = json.loads((report / "metrics.json").read_text())
    assert m["n_samples"] == record["held"].n and m["provenance"]["record_part"]["start_s"] == 56.0
    assert m["vaf"] == pytest.approx(record["vaf"], abs=1e-9)
    assert m["provenance"]["record_samples"] == 24000  # the trials cut to the same stretch at 1 kHz
    assert abs(m["vaf_cosim"] - m["vaf"]) < 2.0


def test_improve_splits_one_record(record, capsys):
    status, out, err = _cli(["-q", "improve", "--pt", record["pt"], "--ut", record["ut"], "--hold-out", "0.3",
                             "--max-steps", "1", "--report", record["folder"] / "improve", "-o",
                             record["folder"] / "improved.json"], capsys)
    assert status == 0, err
    assert "held out:  56.0..80.0 s of the 80.0 s record (--hold-out 0.3); identified on 0.0..56.0 s" in out
    h = LPVPCModel.load(record["folder"] / "improved.json").fit["hold_out"]
    assert h["held_out_s"] == [56.0, 80.0] and h["value"] == 0.3


@pytest.mark.parametrize("value, needle", [
    ("0", "a fraction must lie between 0 and 1"),
    ("1", "a fraction must lie between 0 and 1"),
    ("-0.3", "a fraction must lie between 0 and 1"),
    ("1.5", "a fraction must lie between 0 and 1"),
    ("abc", "give a fraction"),
    ("60:50", "STOP must come after START"),
    ("30:30", "STOP must come after START"),
    ("0:30", "START must lie after the record's start"),
    ("-5:30", "START must lie after the record's start"),
    ("70:120", "does not lie inside the record's 0..80.0 s"),
    ("0.95", "leaves the identification part 4.0 s (at least 10 s each)"),
    ("75:", "leaves the held-out part 5.0 s"),
])
def test_bad_values_are_one_line(record, capsys, value, needle, tmp_path):
    status, out, err = _cli(["-q", "identify", "--pt", record["pt"], "--ut", record["ut"], f"--hold-out={value}",
                             "-o", tmp_path / "m.json"], capsys)
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("lpvpc: error: ") and needle in lines[0], err
    assert not (tmp_path / "m.json").exists()


def test_misuses_are_one_line(record, capsys, tmp_path):
    pt, ut, model_file = record["pt"], record["ut"], record["model_file"]
    other = tmp_path / "other.json"
    record["model"].save(other)  # identified in Python: records no hold-out
    cases = [
        (["diagnose", other, "--pt", pt, "--ut", ut, "--hold-out"], "this model records none"),
        (["diagnose", model_file, "--pt", pt, "--ut", ut, "--hold-out", "0.5"],
         "identified on this record with --hold-out 0.3 (held out 56.0..80.0 s)"),
        (["validate", model_file, "--pt", pt, "--ut", ut, "--hold-out", "0.5", "--report", tmp_path / "r"],
         "identified on this record with --hold-out 0.3"),
        (["identify", "--pt", pt, "--ut", ut, "--hold-out", "-o", tmp_path / "m.json"], "needs FRACTION or START:STOP"),
        (["improve", "--pt", pt, "--ut", ut, "--hold-out", "0.3", "--heldout-pt", pt, "--heldout-ut", ut, "--report",
          tmp_path / "i"], "not both"),
        (["identify", "--pt", pt, "--ut", ut, "--pt", pt, "--ut", ut, "--hold-out", "0.3", "-o", tmp_path / "m.json"],
         "splits one record"),
        (["diagnose", model_file, "--hold-out", pt], "the record"),
    ]
    for argv, needle in cases:
        status, _, err = _cli(["-q", *argv], capsys)
        lines = err.strip().splitlines()
        assert status == 2 and len(lines) == 1 and needle in lines[0], (argv, err)
