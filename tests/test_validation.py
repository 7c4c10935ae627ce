"""The validation harness (``lpvpc validate``, package ``validation``): prediction routes,
co-simulation of the model FMU with the actuator FMU, the report (opened in headless
Chromium), thresholds and bad input.

One full run on the virtual subject's novel (held-out) trajectory is shared by the module;
the other cases use a 20-s cut of the same record so that the module stays well under a
minute and a half.
"""

import base64
import contextlib
import io
import json
import os
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
import report_browser
from report_browser import assert_layout_ok, check_page

from lpvpc.cli import build_parser, main
from lpvpc.cli.validate import run as cmd_validate
from lpvpc.io import Trial, decimate_trial, write_trial_csv
from lpvpc.errors import DataError, FMUError
from lpvpc.models.model import LPVPCModel, vaf
from lpvpc.validation import CosimSettings, validate
from lpvpc.validation.cosim import ActuatorDrive, _check_finite, run_cosimulation
from lpvpc.validation.fmu import inspect_fmu
from lpvpc.validation.report import FIGURES

SHORT_S = 20.0  # s, length of the cut record


def _run(argv):
    """Run the CLI in-process: (exit status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


def _one_line_error(rc, err, *needles):
    assert rc == 2, err
    # one error line; progress lines ("lpvpc: [  3.1 s] ...") may come before it
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("lpvpc: [")]
    assert len(lines) == 1, lines
    assert lines[0].startswith("lpvpc: error: "), lines
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def full(subject, model_file, tmp_path_factory):
    """``lpvpc validate`` on the whole novel record (2 min at 1 kHz), --min-vaf 90."""
    folder = subject["folder"]
    report = tmp_path_factory.mktemp("validation") / "report"
    rc, out, err = _run(["validate", model_file, "--pt", folder / "novel_PT.csv", "--ut", folder / "novel_UT.csv",
                         "--report", report, "--min-vaf", "90"])
    metrics = json.loads((report / "metrics.json").read_text())
    # the latency-free causal FMU, and the full-band command (library calls, no report)
    kw = dict(actuator_fmu=report / "fmus" / "actuator_fmi2.fmu", measure_load_effect=False, write_report=False)
    causal = validate(model_file, folder / "novel_PT.csv", folder / "novel_UT.csv", report.parent / "causal",
                      fmu_variant="causal", **kw)
    full_band = validate(model_file, folder / "novel_PT.csv", folder / "novel_UT.csv", report.parent / "full_band",
                         fmu=report / "fmus" / "model_exact_fmi2.fmu", band_limit_command=False, **kw)
    return {"rc": rc, "out": out, "err": err, "report": report, "metrics": metrics, "causal": causal.metrics,
            "full_band": full_band.metrics}


@pytest.fixture(scope="module")
def short(subject, tmp_path_factory):
    """The first 20 s of the novel record as CSV (1 kHz, with and without the command
    channel, and decimated to 100 Hz)."""
    folder = tmp_path_factory.mktemp("short")
    pair = subject["novel_pair"]
    n = int(SHORT_S * 1000)
    paths = {}
    for key, tr in (("PT", pair.pt), ("UT", pair.ut)):
        cut = Trial(tr.time[:n], tr.position[:n], tr.torque[:n], {k: v[:n] for k, v in tr.channels.items()},
                    name=tr.name)
        write_trial_csv(cut, folder / f"{key}.csv")
        write_trial_csv(Trial(cut.time, cut.position, cut.torque, {}, name=tr.name), folder / f"{key}_nocmd.csv")
        low = decimate_trial(cut, 100.0)  # what a lab stores at 100 Hz: anti-aliased
        paths[key] = folder / f"{key}.csv"
        paths[key + "_nocmd"] = folder / f"{key}_nocmd.csv"
        paths[key + "_raw"] = cut
        paths[key + "_low"] = low
    paths["folder"] = folder
    return paths


def test_validate_writes_report_metrics_and_figures(full):
    assert full["rc"] == 0, full["err"]
    report = full["report"]
    assert (report / "report.html").is_file()
    for name in FIGURES:
        png = report / "figures" / name
        assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    m = full["metrics"]
    for key in ("vaf", "vaf_fmu", "vaf_cosim", "rmse", "rmse_fmu", "rmse_cosim", "route_agreement", "scheduling",
                "checks", "pass", "provenance", "cosim"):
        assert key in m, key
    assert m["pass"] is True and all(c["pass"] for c in m["checks"])
    assert [c["name"] for c in m["checks"][:3]] == ["vaf >= min_vaf", "vaf_fmu >= min_vaf", "vaf_cosim >= min_vaf"]
    prov = m["provenance"]
    assert prov["model_hash"] == LPVPCModel.load(prov["model_file"]).model_hash
    assert re.fullmatch(r"[0-9a-f]{64}", prov["model_fmu"]["sha256"])
    assert re.fullmatch(r"[0-9a-f]{64}", prov["data_files"]["pt"]["sha256"])
    assert prov["step_sizes"] == {"model_s": 0.01, "actuator_s": 0.001, "communication_s": 0.01}
    assert {"numpy", "scipy", "casadi", "fmpy", "lpvpc", "python"} <= set(prov["versions"])
    assert "report:" in full["out"] and "result:      pass" in full["out"]


def test_vaf_of_every_route_against_the_noise_ceiling(full, subject, model):
    """The noise ceiling is the VAF of the true noise-free perturbation torque on the same
    noisy record."""
    m = full["metrics"]
    ceiling = vaf(subject["novel"].torque, subject["novel_clean"].torque)
    assert m["n_samples"] == subject["novel"].n
    assert m["vaf"] >= ceiling - 1.0, (m["vaf"], ceiling)
    # The default validation runs the exact FMU (the identified two-sided model; its latency
    # of L samples removed when comparing, and in the loop its torque loads the actuator L
    # steps late) with the command band-limited to the model's band: all three routes land
    # within 1 point. The FMU equals the offline prediction it computes: the model on the model
    # rate's velocity, which is the headline itself unless the reflex sees the file's 1 kHz one.
    assert m["cosim"]["model_fmu_variant"] == "exact" and m["cosim"]["model_fmu_latency_samples"] == model.lags[-1]
    assert m["cosim"]["settings"]["band_limit_command"] is True
    same = m["routes"].get("numpy_model_rate", m["routes"]["numpy"])
    assert m["vaf_fmu"] == pytest.approx(same["vaf"], abs=1e-9)
    assert (model.high_rate is not None) == ("numpy_model_rate" in m["routes"])
    assert m["vaf_fmu"] >= ceiling - 1.0, (m["vaf_fmu"], ceiling)
    assert m["vaf_cosim"] >= ceiling - 1.0, (m["vaf_cosim"], ceiling)
    # The causal FMU (latency-free, for closed loop) loses ~0.6 points to the two-sided
    # model: its replay equals the offline causal form; in the loop it stays within 1.3.
    c = full["causal"]
    assert c["cosim"]["model_fmu_variant"] == "causal"
    assert c["vaf_fmu"] == pytest.approx(m["vaf_causal"], abs=1e-9)
    assert m["vaf"] - 1.0 < c["vaf_fmu"] < m["vaf"]
    assert c["vaf_cosim"] >= ceiling - 1.3, (c["vaf_cosim"], ceiling)
    # Without the band limit the actuators' faster motion reaches the 100 Hz model sampled
    # every 10 ms, not anti-aliased as the identification data were: that costs about a
    # point, and replaying the same co-simulated positions recorded at 1 kHz and decimated
    # like the measured data recovers it.
    f = full["full_band"]
    assert f["cosim"]["settings"]["band_limit_command"] is False
    assert f["vaf_cosim"] < m["vaf_cosim"]
    assert f["vaf_actuator_replay"] > f["vaf_cosim"] + 0.3
    assert abs(f["vaf_actuator_replay"] - f["vaf_fmu"]) < 0.3


def test_prediction_routes_agree(full):
    ag = full["metrics"]["route_agreement"]
    for key in ("casadi_vs_numpy_causal", "fmu_vs_numpy", "casadi_exact_vs_numpy"):
        assert ag[key]["max_relative_difference"] <= 1e-9, (key, ag[key])
        assert ag[key]["pass"]
    assert ag["pass"]
    m = full["metrics"]
    assert abs(m["vaf_fmu"] - m["routes"].get("numpy_model_rate", m["routes"]["numpy"])["vaf"]) < 1e-9
    assert abs(m["vaf_casadi"] - m["vaf_causal"]) < 1e-9
    for route in ("fmu", "casadi_exact"):  # the latency is removed without losing the record's last samples
        assert m["routes"][route]["n"] == m["n_samples"]
    c = full["causal"]["route_agreement"]
    assert c["fmu_vs_numpy_causal"]["max_relative_difference"] <= 1e-9 and c["pass"]


def test_out_of_range_is_flagged_and_its_error_shown_separately(full, subject, model):
    sched = full["metrics"]["scheduling"]
    rho = subject["novel"].scheduling
    lo, hi = model.scheduling_range
    outside = (rho < lo) | (rho > hi)
    assert outside.any()  # the novel trajectory leaves the identified range on purpose
    assert sched["flagged"] is True
    assert sched["out_of_range_fraction"] == pytest.approx(outside.mean())
    assert full["metrics"]["out_of_range_fraction"] == sched["out_of_range_fraction"]
    assert sched["heldout_range"][0] < lo and sched["heldout_range"][1] > hi
    for name in ("numpy", "fmu", "cosim"):
        assert sched["out_of_range"][name]["n"] == int(outside.sum())
        assert sched["in_range"][name]["n"] == int((~outside).sum())
        assert sched["out_of_range"][name]["rmse"] > 0
    page = (full["report"] / "report.html").read_text()
    assert "outside the identified range" in page.lower()
    assert "range:" in full["out"]
    rows = full["metrics"]["failure_analysis"]["by_position"]
    assert rows[0]["hi"] <= lo + 1e-12 and rows[-1]["lo"] >= hi - 1e-12  # separate out-of-range bins


def test_cosimulation_calibrates_the_actuator_and_measures_the_load(full):
    c = full["metrics"]["cosim"]
    # the virtual subject's servo: 25 Hz, damping 0.7 (the actuator FMU defaults to 40 Hz)
    assert c["calibration"]["done"]
    assert c["calibration"]["servo_bandwidth"] == pytest.approx(25.0, rel=1e-3)
    assert c["calibration"]["servo_damping"] == pytest.approx(0.7, rel=1e-3)
    assert c["command_source"].startswith("the record's command channel, band-limited")
    assert c["tracking"]["perturbation_position_vaf"] > 99.9
    le = c["load_effect"]
    assert le["perturbation_position_max_mrad"] < 2.0  # stiff servo: 0.05 mrad per N m
    assert abs(le["vaf_change"]) < 0.3
    assert c["settings"]["coupling"] == "iterate" and c["iterations"]["max"] == 1  # the exact FMU: no loop to iterate
    assert c["actuator_steps_per_model_step"] == 10
    assert c["real_time_factor"] > 1.0
    assert {x["to"] for x in c["connections"]} == {
        "actuator_ut.command", "actuator_pt.command", "actuator_ut.load_torque", "actuator_pt.load_torque",
        "model.position", "model.scheduling"}  # the exact FMU has no velocity/acceleration inputs


def test_report_is_self_contained(full):
    page = (full["report"] / "report.html").read_text()
    srcs = re.findall(r'<img[^>]*\ssrc="([^"]+)"', page)
    assert len(srcs) == len(FIGURES)
    for s in srcs:
        assert s.startswith("data:image/png;base64,")
        assert base64.b64decode(s.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    assert not re.search(r'(src|href)="(https?:)?//', page)
    assert "<link" not in page
    for title in ("Fig. 3", "Fig. 4", "Fig. 5", "Where the model fails", "Provenance", "Scheduling range"):
        assert title in page
    # the order a scientist reads: the answer, then folded physiology, prediction, software checks, provenance
    order = [page.index(h) for h in ('<section class="answer"', "<summary>Physiology", "<summary>Prediction",
                                     "<summary>Software checks", "<summary>Provenance")]
    assert order == sorted(order)
    physiology = page[order[0]:page.index("</section>")]
    assert "elastic stiffness K (N m/rad)" in physiology and "reflex threshold (rad/s)" in physiology
    # 5 positions x 4 quantities with intervals, or "not determined" (a threshold seen on 100 Hz velocity)
    assert physiology.count("–") + physiology.count("not determined by these data") >= 20
    text = re.sub(r"base64,[A-Za-z0-9+/=]+", "", page)
    assert not re.search(r"[-+]0\.0+(?![0-9])", text), "a signed zero such as -0.00 in the report"


def test_report_renders_in_headless_chromium(full, tmp_path):
    """Chromium opens report.html offline at 1280 px: every figure loads, nothing overflows
    the page width (tests/report_browser.py); the page's own script marks every <img> that
    decoded. The screenshot goes to $LPVPC_SCREENSHOT_DIR when set (for looking at it)."""
    shots = Path(os.environ.get("LPVPC_SCREENSHOT_DIR") or tmp_path)
    check = check_page(full["report"] / "report.html", shots / "validate_report.png")
    assert_layout_ok(check, n_images=len(FIGURES))
    assert check.screenshot.stat().st_size > 10_000


def test_min_vaf_failing_exits_1(full, short, model_file, tmp_path):
    """The validate command's handler (what main calls once the command line is parsed)
    returns 1 when a check fails, after writing the report and the metrics."""
    fmus = full["report"] / "fmus"
    args = build_parser().parse_args([str(a) for a in (
        "validate", model_file, "--pt", short["PT"], "--ut", short["UT"], "--report", tmp_path / "r", "--min-vaf",
        "99.9", "--fmu", fmus / "model_exact_fmi2.fmu", "--actuator-fmu", fmus / "actuator_fmi2.fmu")])
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = cmd_validate(args)
    out = out.getvalue()
    assert rc == 1, out
    assert "FAILED:      vaf >= min_vaf" in out and "result:      FAIL" in out
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["pass"] is False and not m["checks"][0]["pass"]
    assert m["provenance"]["model_fmu"]["given"] is True
    assert (tmp_path / "r" / "report.html").is_file()


# --------------------------------------------------------------------------- bad input


def test_missing_and_corrupt_fmu_exit_2(short, model_file, tmp_path):
    base = ["validate", model_file, "--pt", short["PT"], "--ut", short["UT"], "--report", tmp_path / "r"]
    _one_line_error(*_run(base + ["--fmu", tmp_path / "nope.fmu"])[::2], "nope.fmu", "file not found")
    bad = tmp_path / "corrupt.fmu"
    bad.write_bytes(b"PK\x03\x04 this is not a zip archive" * 10)
    _one_line_error(*_run(base + ["--fmu", bad])[::2], "corrupt FMU")
    nodesc = tmp_path / "nodesc.fmu"
    with zipfile.ZipFile(nodesc, "w") as zf:
        zf.writestr("binaries/linux64/x.so", b"\0")
    _one_line_error(*_run(base + ["--fmu", nodesc])[::2], "no modelDescription.xml")


def test_fmu_for_another_platform_exits_2(full, short, model_file, tmp_path):
    src = full["report"] / "fmus" / "model_exact_fmi2.fmu"
    other = tmp_path / "mac_only.fmu"
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(other, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            name = item.filename
            if name.startswith("binaries/linux64/"):
                name = name.replace("binaries/linux64/", "binaries/darwin64/").replace(".so", ".dylib")
            zout.writestr(name, zin.read(item.filename))
    rc, _, err = _run(["validate", model_file, "--pt", short["PT"], "--ut", short["UT"], "--report", tmp_path / "r",
                       "--fmu", other])
    _one_line_error(rc, err, "built for another platform", "darwin64", "fmpy compile")


def test_fmu_of_another_model_exits_2(full, short, model, tmp_path):
    d = model.to_dict()
    d["reflex"]["D"] = float(d["reflex"]["D"]) + 1e-3
    other = tmp_path / "other.json"
    other.write_text(json.dumps(d))
    rc, _, err = _run(["validate", other, "--pt", short["PT"], "--ut", short["UT"], "--report", tmp_path / "r",
                       "--fmu", full["report"] / "fmus" / "model_exact_fmi2.fmu"])
    _one_line_error(rc, err, "exported from model")


def test_fmu_that_is_not_a_model_fmu_is_refused(full, short, model_file, tmp_path):
    rc, _, err = _run(["validate", model_file, "--pt", short["PT"], "--ut", short["UT"], "--report", tmp_path / "r",
                       "--fmu", full["report"] / "fmus" / "actuator_fmi2.fmu"])
    _one_line_error(rc, err, "lacks input 'position', input 'scheduling', output 'torque'")


def test_missing_chromium_fails_unless_allowed(monkeypatch):
    monkeypatch.setattr(report_browser, "CHROMIUM", "/nonexistent/chromium")
    monkeypatch.delenv("LPVPC_ALLOW_NO_CHROMIUM", raising=False)
    with pytest.raises(pytest.fail.Exception, match="not installed"):
        report_browser.chromium_or_skip()
    monkeypatch.setenv("LPVPC_ALLOW_NO_CHROMIUM", "1")
    with pytest.raises(pytest.skip.Exception, match="LPVPC_ALLOW_NO_CHROMIUM"):
        report_browser.chromium_or_skip()


def test_layout_check_sees_a_table_that_scrolls_sideways(tmp_path):
    """The Chromium layout check flags a table wider than its scrolling box (a reader would
    scroll sideways to see its last column), and passes the same table once its long words
    may wrap."""
    cell = "position_dependent_reflex_dynamics_" * 3
    page = ('<!DOCTYPE html><html><body style="max-width:600px"><div style="overflow-x:auto">'
            '<table><tr><td>{}</td><td>{}</td></tr></table></div></body></html>')
    wide, wrapped = tmp_path / "wide.html", tmp_path / "wrapped.html"
    wide.write_text(page.format(cell, cell))
    wrapped.write_text(page.format(*[f'<span style="overflow-wrap:anywhere">{cell}</span>'] * 2))
    assert any("hides content sideways" in p for p in check_page(wide).problems())
    assert check_page(wrapped).problems() == []


def test_records_of_different_lengths_exit_2(short, model_file, tmp_path):
    ut = short["UT_raw"]
    n = len(ut.time) - 500
    path = tmp_path / "UT_short.csv"
    write_trial_csv(Trial(ut.time[:n], ut.position[:n], ut.torque[:n], {k: v[:n] for k, v in ut.channels.items()}),
                    path)
    rc, _, err = _run(["validate", model_file, "--pt", short["PT"], "--ut", path, "--report", tmp_path / "r"])
    _one_line_error(rc, err, "differ in length")


def test_model_record_rate_mismatch_exits_2(short, model_file, tmp_path):
    paths = {}
    for key in ("PT", "UT"):
        tr = short[key + "_raw"]
        paths[key] = tmp_path / f"{key}_50Hz.csv"  # the same samples stamped at 50 Hz
        write_trial_csv(Trial(np.arange(len(tr.time)) / 50.0, tr.position, tr.torque, dict(tr.channels)),
                        paths[key])
    rc, _, err = _run(["validate", model_file, "--pt", paths["PT"], "--ut", paths["UT"], "--report", tmp_path / "r"])
    _one_line_error(rc, err, "50 Hz", "below the target rate", "100 Hz")


def test_fmu_error_is_reported_with_the_fmus_log(full, short, model_file, tmp_path):
    fmus = full["report"] / "fmus"
    rc, _, err = _run(["validate", model_file, "--pt", short["PT"], "--ut", short["UT"], "--report", tmp_path / "r",
                       "--fmu", fmus / "model_exact_fmi2.fmu", "--actuator-fmu", fmus / "actuator_fmi2.fmu",
                       "--actuator-param", "servo_bandwidth=-1"])
    _one_line_error(rc, err, "actuator_ut", "ExitInitializationMode", "FMU log:", "sys_initial_state failed (code 1)")
    rc, _, err = _run(["validate", model_file, "--pt", short["PT"], "--ut", short["UT"], "--report", tmp_path / "r",
                       "--actuator-fmu", fmus / "actuator_fmi2.fmu", "--actuator-param", "no_such_thing=1"])
    _one_line_error(rc, err, "no parameter named 'no_such_thing'")


def test_non_finite_output_is_an_error():
    with pytest.raises(FMUError, match=r"model: output 'torque_reflex' is nan \(not finite\) at t = 1.23 s"):
        _check_finite([1.0, 2.0, float("nan")], "model", ("torque", "torque_intrinsic", "torque_reflex"), 1.23)


# --------------------------------------------------------------------------- library


def _drive(short, ratio=10, seconds=5.0):
    pt, ut = short["PT_raw"], short["UT_raw"]
    n = int(seconds * 1000)
    return ActuatorDrive(ut.channels["command"][:n], pt.channels["command"][:n], ut.torque[:n], 1e-3, ratio,
                         n // ratio, "test")


def test_fmi3_cosimulation_equals_fmi2_and_couplings_agree(full, short, model, tmp_path):
    from lpvpc.export.actuator import build_actuator_fmu
    from lpvpc.export.exporter import export_fmu

    fmus = full["report"] / "fmus"
    m2, a2 = inspect_fmu(export_fmu(model, tmp_path / "m2.fmu")), inspect_fmu(fmus / "actuator_fmi2.fmu")
    m3 = inspect_fmu(export_fmu(model, tmp_path / "m3.fmu", fmi_version=3))
    a3 = inspect_fmu(build_actuator_fmu(tmp_path / "a3.fmu", fmi_version=3))
    params = full["metrics"]["cosim"]["actuator_parameters"]
    drive = _drive(short)
    r2 = run_cosimulation(m2, a2, drive, actuator_parameters=params)
    r3 = run_cosimulation(m3, a3, drive, actuator_parameters=params)
    assert np.max(np.abs(r3.torque - r2.torque)) <= 1e-12 * np.max(np.abs(r2.torque))
    assert np.all(np.isfinite(r2.pt)) and np.all(np.isfinite(r2.ut))
    # the one-step-delay coupling differs from the converged iteration only slightly
    rd = run_cosimulation(m2, a2, drive, settings=CosimSettings(coupling="delay"), actuator_parameters=params)
    assert rd.iterations.max() == 1 and r2.iterations.max() <= 5
    assert np.sqrt(np.mean((rd.torque - r2.torque) ** 2)) < 0.05 * np.std(r2.torque)
    # converged: the torque applied to the PT actuator is the model's output of that step
    assert np.max(np.abs(r2.load_pt_model - r2.torque)) <= 1e-6


def test_exact_fmu_in_the_loop_loads_the_actuator_with_its_latency(full, short, model):
    """The exact FMU's output at step k is the torque of k - L: the master shifts it back to
    its time and applies it to the PT actuator over step k (L steps late), and a latency
    that does not match the FMU's variant is refused."""
    from lpvpc.export.exporter import latency_samples

    fmus = full["report"] / "fmus"
    m_ex, act = inspect_fmu(fmus / "model_exact_fmi2.fmu"), inspect_fmu(fmus / "actuator_fmi2.fmu")
    lat = latency_samples(model, "exact")
    drive = _drive(short)
    r = run_cosimulation(m_ex, act, drive, actuator_parameters=full["metrics"]["cosim"]["actuator_parameters"],
                         latency=lat)
    assert r.variant == "exact" and r.latency == lat == model.lags[-1]
    assert len(r.torque) == drive.n_model and np.all(np.isfinite(r.torque))
    assert np.array_equal(r.load_pt_model[lat:], r.torque[:-lat]) and np.all(r.load_pt_model[:lat] == 0.0)
    assert "model.velocity" not in dict(r.connections)
    # the torque is the two-sided model of what the model FMU received
    p = model.predict(r.model_inputs["position"], r.model_inputs["scheduling"], warn=False).total
    assert np.max(np.abs(p - r.torque)[:-lat]) <= 1e-9 * np.max(np.abs(p))
    with pytest.raises(FMUError, match="variant exact with latency 0"):
        run_cosimulation(m_ex, act, drive, latency=0)


def test_record_without_command_and_100hz_record(full, short, model, tmp_path):
    fmus = full["report"] / "fmus"
    kw = dict(fmu=fmus / "model_exact_fmi2.fmu", actuator_fmu=fmus / "actuator_fmi2.fmu", write_report=False,
              measure_load_effect=False)
    # no command channel: the measured positions drive the actuator through the inverse servo,
    # and iterative learning refines that command until the actuators reproduce them
    r = validate(model, short["PT_nocmd"], short["UT_nocmd"], tmp_path / "nocmd",
                 actuator_parameters={"servo_bandwidth": 25.0, "servo_damping": 0.7}, **kw)
    c = r.metrics["cosim"]
    assert "no command channel" in c["command_source"] and not c["calibration"]["done"]
    rms = c["command_refinement"]["tracking_rms_mrad"]
    assert c["command_refinement"]["passes"] >= 1 and rms[-1] < 0.05 * rms[0], rms
    assert c["tracking"]["perturbation_position_vaf"] > 99.999
    assert abs(r.metrics["vaf_cosim"] - r.metrics["vaf_fmu"]) < 0.1  # what is left: the coupling, not the drive
    # a 100 Hz record: the command is interpolated to the actuator's 1 kHz, the servo calibrated
    r = validate(model, short["PT_low"], short["UT_low"], tmp_path / "low", **kw)
    c = r.metrics["cosim"]
    assert c["calibration"]["done"] and c["calibration"]["servo_bandwidth"] == pytest.approx(25.0, rel=0.05)
    assert r.metrics["provenance"]["record_fs"] == pytest.approx(100.0)
    assert r.metrics["vaf_cosim"] > r.metrics["vaf_fmu"] - 1.5
    # a 1024 Hz record (a rate that is not a multiple of the model's): read at 1000 Hz, as
    # identification reads it, and validated like the 1 kHz record
    import scipy.signal

    at_1k = validate(model, short["PT"], short["UT"], tmp_path / "1k", **kw).metrics
    paths = {}
    for key in ("PT", "UT"):
        tr = short[key + "_raw"]
        res = {k: scipy.signal.resample_poly(v, 128, 125) for k, v in
               {"position": tr.position, "torque": tr.torque, **tr.channels}.items()}
        paths[key] = tmp_path / f"{key}_1024.csv"
        write_trial_csv(Trial(np.arange(len(res["position"])) / 1024.0, res.pop("position"), res.pop("torque"), res),
                        paths[key])
    r = validate(model, paths["PT"], paths["UT"], tmp_path / "1024", **kw).metrics
    assert r["provenance"]["record_fs"] == pytest.approx(1000.0) and r["provenance"]["record_fs_file"] == pytest.approx(1024.0)
    assert r["vaf_cosim"] == pytest.approx(at_1k["vaf_cosim"], abs=0.1)


def test_other_column_names_are_read_with_channel_options(full, short, model_file, tmp_path):
    """A lab's own column names: without --channel the missing role is named (one line, exit
    2); with --channel the record validates as the package's own names do."""
    paths = {}
    for key in ("PT", "UT"):
        lines = short[key].read_text().splitlines()
        header = lines[0].split(",")
        assert header[:3] == ["time", "position", "torque"], header
        lines[0] = ",".join(["t (s)", "Ankle angle (rad)", "Torque (N m)", *header[3:]])
        paths[key] = tmp_path / f"{key}_lab.csv"
        paths[key].write_text("\n".join(lines) + "\n")
    base = ["validate", model_file, "--pt", paths["PT"], "--ut", paths["UT"]]
    rc, _, err = _run([*base, "--report", tmp_path / "r0"])
    _one_line_error(rc, err, "position")
    fmus = full["report"] / "fmus"
    rc, out, err = _run([*base, "--report", tmp_path / "r", "--channel", "time=t (s)", "--channel",
                         "position=Ankle angle (rad)", "--channel", "torque=Torque (N m)",
                         "--fmu", fmus / "model_exact_fmi2.fmu", "--actuator-fmu", fmus / "actuator_fmi2.fmu"])
    assert rc == 0, err
    named = json.loads((tmp_path / "r" / "metrics.json").read_text())
    rc, _, err = _run(["validate", model_file, "--pt", short["PT"], "--ut", short["UT"], "--report", tmp_path / "own",
                       "--fmu", fmus / "model_exact_fmi2.fmu", "--actuator-fmu", fmus / "actuator_fmi2.fmu"])
    assert rc == 0, err
    own = json.loads((tmp_path / "own" / "metrics.json").read_text())
    assert named["vaf"] == pytest.approx(own["vaf"], abs=1e-9) and named["n_samples"] == own["n_samples"]


def test_a_pt_minus_ut_file_validates_like_its_two_trials(full, short, model_file, tmp_path):
    """One PT - UT file with a scheduling column (the lab pilot's format) as DATA: its two
    trials rebuilt (UT = the scheduling, PT = scheduling + perturbation), the same offline and
    FMU prediction as the PT and UT files, the co-simulation loading the PT actuator with the
    model's torque only (the file has no UT torque), and the report says so. Mixed with --pt,
    or with a whole-joint model (which needs the PT trial's total torque): one line, exit 2."""
    pt, ut = short["PT_raw"], short["UT_raw"]
    data = tmp_path / "pert.csv"
    write_trial_csv(Trial(pt.time, pt.position - ut.position, pt.torque - ut.torque, {"scheduling": ut.position}),
                    data)
    fmus = full["report"] / "fmus"
    given = ["--fmu", fmus / "model_exact_fmi2.fmu", "--actuator-fmu", fmus / "actuator_fmi2.fmu"]
    rc, out, err = _run(["validate", model_file, data, "--report", tmp_path / "d", *given])
    assert rc == 0, err
    rc, _, err = _run(["validate", model_file, "--pt", short["PT_nocmd"], "--ut", short["UT_nocmd"], "--report",
                       tmp_path / "two", *given])
    assert rc == 0, err
    d, two = (json.loads((tmp_path / f / "metrics.json").read_text()) for f in ("d", "two"))
    assert d["vaf"] == pytest.approx(two["vaf"], abs=1e-6) and d["vaf_fmu"] == pytest.approx(two["vaf_fmu"], abs=1e-6)
    assert d["cosim"]["settings"]["load"] == "model" and two["cosim"]["settings"]["load"] == "measured_ut+model"
    assert d["vaf_cosim"] > d["vaf_fmu"] - 1.0
    assert set(d["provenance"]["data_files"]) == {"data"}
    assert "one PT - UT file" in (tmp_path / "d" / "report.html").read_text()
    rc, _, err = _run(["validate", model_file, data, "--pt", short["PT"], "--report", tmp_path / "x"])
    _one_line_error(rc, err, "either DATA or --pt and --ut")
    rc, _, err = _run(["validate", model_file, "--pt", short["PT"], "--report", tmp_path / "x"])
    _one_line_error(rc, err, "missing --ut")
    wj = tmp_path / "wj.json"
    assert main(["whole-joint", str(model_file), "--ut", str(short["UT"]), "-o", str(wj)]) == 0
    rc, _, err = _run(["validate", model_file, data, "--report", tmp_path / "y", "--whole-joint", wj])
    _one_line_error(rc, err, "total torque")


def test_a_stationary_trial_validates_alone(full, tmp_path):
    """A trial around one fixed position recorded without UT (--stationary), as identify and
    predict read it: the UT actuator holds the trial's mean position, loaded by its mean torque;
    the offline VAF is predict's; the report shows its one operating position. With --ut: one
    line, exit 2; with a whole-joint model: refused before anything is read."""
    from lpvpc.simulation.simulate import simulate_pair

    pt = simulate_pair("stationary", seed=2, duration=40.0).pt
    k = int(0.7 * len(pt.time))
    first, held = tmp_path / "a.csv", tmp_path / "b.csv"
    write_trial_csv(Trial(pt.time[:k], pt.position[:k], pt.torque[:k], {}), first)
    write_trial_csv(Trial(pt.time[k:] - pt.time[k], pt.position[k:], pt.torque[k:], {}), held)
    m = tmp_path / "m.json"
    assert main(["identify", "--pt", str(first), "--stationary", "-o", str(m), "-q"]) == 0
    rc, out, err = _run(["validate", m, "--pt", held, "--stationary", "--report", tmp_path / "r",
                         "--actuator-fmu", full["report"] / "fmus" / "actuator_fmi2.fmu"])
    assert rc == 0, err
    assert "identified at one operating position" in out and "outside the identified" not in out
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    rc, _, err = _run(["predict", m, "--pt", held, "--stationary", "--json", tmp_path / "p.json", "-q"])
    assert rc == 0, err
    # a record off the one position is not "outside the identified range [op, op]": how far it lies, and why it matters
    assert "identified at one operating position" in err and "outside the identified range" not in err
    assert metrics["vaf"] == pytest.approx(json.loads((tmp_path / "p.json").read_text())["vaf"], abs=1e-9)
    # no command channel: the refined command reproduces the positions, the co-simulation the replay
    assert abs(metrics["vaf_cosim"] - metrics["vaf_fmu"]) < 0.1 and metrics["vaf"] > 90.0
    assert metrics["provenance"]["data_files"]["ut"]["sha256"] is None
    # one operating position: its values there, and how far the held-out record lies from it
    page = (tmp_path / "r" / "report.html").read_text()
    assert "At the one operating position" in page and "Away from the identified position" in page
    assert "Outside the identified range" not in page
    rc, _, err = _run(["validate", m, "--pt", held, "--ut", held, "--stationary", "--report", tmp_path / "x"])
    _one_line_error(rc, err, "--stationary validates one perturbed trial")
    rc, _, err = _run(["validate", m, "--pt", held, "--report", tmp_path / "x"])
    _one_line_error(rc, err, "missing --ut", "--stationary")
    with pytest.raises(DataError, match="whole-joint model follows the UT trial"):  # refused before anything is read
        validate(m, held, None, tmp_path / "y", stationary=True, whole_joint=tmp_path / "any.json")


def test_summary_does_not_quote_a_reflex_gain_the_data_do_not_determine(model, monkeypatch):
    """The report's summary quotes the reflex gain at the range's ends only where the table
    does: an end the data do not determine is said to be so, not given as a number."""
    from lpvpc.models.uncertainty import NOT_DETERMINED
    from lpvpc.validation.report import _physiology_sentence

    lo, hi = model.scheduling_range
    g = model.reflex_gain_threshold([lo, hi])[0]
    both = _physiology_sentence(model)
    assert f"from {g[0]:.1f} to {g[1]:.1f} N m s/rad" in both and NOT_DETERMINED not in both
    monkeypatch.setattr(type(model), "reflex_determined",
                        lambda self, theta, level=0.95: (np.array([False, True]), np.array([False, True])))
    one = _physiology_sentence(model)
    assert f"{NOT_DETERMINED} at {lo:+.2f} rad and {g[1]:.1f} N m s/rad at {hi:+.2f} rad" in one, one
    assert f"{g[0]:.1f} N m s/rad" not in one
