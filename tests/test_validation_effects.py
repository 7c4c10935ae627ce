"""Validation of an extended model (identified with effects, :mod:`lpvpc.models.effects`):
``lpvpc validate`` feeds the record's extra signals (here ``scheduling_velocity``,
``emg`` and ``emg_ut``) to every route: numpy, CasADi, the FMU replay and the
co-simulation (the model FMU's extra inputs set from the record at each model step).

A 60-s identification record and a 20-s held-out record of the virtual subject with
background activation and nonlinear viscosity; the module runs in about 10 s.
"""

import contextlib
import io
import json
from math import isfinite

import numpy as np
import pytest

from lpvpc.cli import main
from lpvpc.io import Trial, load_identification_data, write_trial_csv
from lpvpc.models.effects import signals_from_data
from lpvpc.identification.identify import identify
from lpvpc.models.model import vaf
from lpvpc.simulation.simulate import simulate_pair

EFFECTS = ("background_activation", "nonlinear_viscosity")


def _run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def extended(tmp_path_factory):
    """The extended model (file), the held-out trials as CSV and ``lpvpc validate`` on them."""
    folder = tmp_path_factory.mktemp("extended")
    ident = simulate_pair("multilevel", seed=0, effects=EFFECTS, duration=60.0)
    data = load_identification_data(pt=ident.pt, ut=ident.ut)
    assert "emg_ut" in data.extra  # pair_trials keeps the UT trial's EMG
    model = identify(data, effects=EFFECTS)
    model_file = folder / "model.json"
    model.save(model_file)
    novel = simulate_pair("novel", seed=1, effects=EFFECTS, duration=20.0)
    for key, tr in (("PT", novel.pt), ("UT", novel.ut)):
        write_trial_csv(tr, folder / f"{key}.csv")
    report = folder / "report"
    rc, out, err = _run(["validate", model_file, "--pt", folder / "PT.csv", "--ut", folder / "UT.csv",
                         "--report", report])
    metrics = json.loads((report / "metrics.json").read_text())
    return {"model": model, "folder": folder, "model_file": model_file, "rc": rc, "out": out, "err": err,
            "metrics": metrics, "report": report}


def test_extended_model_validates_through_every_route(extended):
    m, model = extended["metrics"], extended["model"]
    assert extended["rc"] == 0, extended["err"]
    assert tuple(model.signals) == ("scheduling_velocity", "emg_ut", "activation")
    assert m["model_signals"] == list(model.signals)

    # the offline VAF of the model on the same record (files read back as validate does)
    folder = extended["folder"]
    held = load_identification_data(pt=folder / "PT.csv", ut=folder / "UT.csv", target_fs=model.fs)
    signals = signals_from_data(held, model)  # the activation with the model's reflex drive, as validate's
    offline = vaf(held.torque, model.predict(held.position, held.scheduling, signals=signals, warn=False).total)
    offline_causal = vaf(held.torque, model.predict(held.position, held.scheduling, causal=True, signals=signals,
                                                    warn=False).total)
    for key in ("vaf", "vaf_causal", "vaf_casadi", "vaf_fmu", "vaf_cosim", "vaf_actuator_replay"):
        assert isfinite(m[key]), key
    assert m["vaf"] == pytest.approx(offline, abs=1e-9)
    assert m["vaf_causal"] == pytest.approx(offline_causal, abs=1e-9)
    assert m["vaf_fmu"] == pytest.approx(offline, abs=1e-9)  # the exact FMU (default), latency removed
    assert m["vaf_casadi"] == pytest.approx(offline_causal, abs=1e-9)
    assert offline > 90.0
    # the co-simulation (actuator in the loop) is a physical, not numerical, difference
    assert abs(m["vaf_cosim"] - m["vaf_fmu"]) < 2.0
    assert abs(m["vaf_actuator_replay"] - m["vaf_fmu"]) < 2.0

    agree = m["route_agreement"]
    for key in ("casadi_vs_numpy_causal", "fmu_vs_numpy", "casadi_exact_vs_numpy"):
        assert agree[key]["max_relative_difference"] <= 1e-9, (key, agree[key])
    assert agree["pass"] and m["pass"]

    # the model FMU's extra inputs come from the record in the co-simulation
    conns = {c["to"]: c["from"] for c in m["cosim"]["connections"]}
    for name in model.signals:
        assert conns[f"model.{name}"].startswith(f"record.{name}")


def test_extended_model_without_its_signals_would_fail_offline(extended):
    """The extra signals matter: without the background activation terms the base model
    explains far less of the same record (so routes that dropped them would show it)."""
    folder, model = extended["folder"], extended["model"]
    held = load_identification_data(pt=folder / "PT.csv", ut=folder / "UT.csv", target_fs=model.fs)
    sig = signals_from_data(held, model)
    flat = {**sig, "activation": np.zeros(held.n), "emg_ut": np.zeros(held.n)}
    with_sig = vaf(held.torque, model.predict(held.position, held.scheduling, signals=sig, warn=False).total)
    without = vaf(held.torque, model.predict(held.position, held.scheduling, signals=flat, warn=False).total)
    assert with_sig - without > 10.0


def test_record_lacking_a_signal_the_model_needs_exits_2(extended, tmp_path):
    """A UT trial without EMG gives no emg_ut: one-line error before any FMU work."""
    novel = simulate_pair("novel", seed=1, effects=EFFECTS, duration=5.0)
    ut = novel.ut
    write_trial_csv(Trial(ut.time, ut.position, ut.torque, {k: v for k, v in ut.channels.items() if k != "emg"},
                          name=ut.name), tmp_path / "UT.csv")
    write_trial_csv(novel.pt, tmp_path / "PT.csv")
    rc, out, err = _run(["validate", extended["model_file"], "--pt", tmp_path / "PT.csv", "--ut", tmp_path / "UT.csv",
                         "--report", tmp_path / "report"])
    assert rc == 2, (out, err)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("lpvpc: error: ") and "emg_ut" in lines[0], lines
    assert not (tmp_path / "report" / "fmus").exists()
