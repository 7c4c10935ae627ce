"""The demo: ``python -m lpvpc.demo OUTDIR`` (what ``make demo`` runs).

1. simulates the virtual subject (2-minute identification and novel trials at 1 kHz,
   with truth) into OUTDIR/data;
2. identifies an LPV-PC model from ident_PT/UT through the file loaders (decimated to
   100 Hz) and saves OUTDIR/model.json;
3. predicts the novel (held-out) trajectory and prints its VAF next to the noise ceiling
   (the VAF of the true, noise-free perturbation torque on the same noisy record);
4. prints the recovered elastic stiffness K(theta) and the reflex gain and threshold
   against the truth;
5. saves the paper's figures in OUTDIR/figures;
6. exports OUTDIR/model.casadi and OUTDIR/model.fmu and runs the FMU on the novel record;
7. validates the model on the novel record (package ``validation``: numpy, CasADi and FMU
   routes, co-simulation of the model FMU with the actuator FMU) and writes the report
   OUTDIR/validation/report.html with metrics.json and the figures;
8. runs the improve loop on a data set with a hidden effect (direction-dependent
   stiffness, OUTDIR/data_hidden): fit, diagnose on the held-out record, add the effect
   the diagnosis names, refit, until nothing significant is left; prints the error
   falling and writes OUTDIR/improve/report.html (and improve.md);
9. fits the closed-loop form of the whole-joint model (angle and angular velocity in, torque
   out, inertia declared) and runs its FMU in a compliant exoskeleton loop beside the virtual
   subject and the replay FMU: OUTDIR/closed_loop/closed_loop.html.

Units: rad, rad/s, N m, N m/rad, s.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

# One BLAS thread unless the user says otherwise: the identification's tall QR and least
# squares gain little from threads, and on a busy machine OpenBLAS threads oversubscribe
# the cores (measured on a loaded 2-core machine: 51 s with threads vs 2.6 s without).
# Effective only when numpy is not imported yet (python -m lpvpc.demo).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from .errors import LpvpcError, LpvpcWarning, OutOfRangeWarning, UnitWarning  # noqa: E402

N_TABLE_POSITIONS = 7
CENTRAL_FRACTION = 0.8


def _say(text=""):
    print(text, flush=True)


def _section(title):
    _say()
    _say(title)
    _say("-" * len(title))


def _central_positions(model, n):
    lo, hi = model.scheduling_range
    margin = (1 - CENTRAL_FRACTION) / 2 * (hi - lo)
    return np.linspace(lo + margin, hi - margin, n)


def _perturbation_truth(trials_npz, target_fs):
    """Noise-free perturbation torque and its intrinsic and reflex parts (N m), through the
    same PT-UT pairing and decimation as the measured data."""
    from .io import Trial, pair_trials

    z = np.load(trials_npz)
    t, pt_pos, ut_pos = z["time"], z["pt_position"], z["ut_position"]
    out = {}
    for key, pt_tq, ut_tq in (("total", z["pt_torque_clean"], z["ut_torque_clean"]),
                              ("intrinsic", z["pt_intrinsic"], z["ut_intrinsic"]),
                              ("reflex", z["pt_reflex"], z["ut_reflex"])):
        pair = pair_trials(Trial(t, pt_pos, pt_tq, name="PT clean"), Trial(t, ut_pos, ut_tq, name="UT clean"),
                           target_fs=target_fs)
        out[key] = pair.torque
    return out


def _run_fmu(fmu_path, position, scheduling):
    """Run the exported FMU over a record the way its user does: ``fmpy.simulate_fmu`` with
    the README's recipe (inputs position and scheduling, the declared step, latency and
    sample period). Returns the torque (N m) aligned with the record and samples/s."""
    from fmpy import read_model_description, simulate_fmu

    md = read_model_description(str(fmu_path))
    constant = {v.name: float(v.start) for v in md.modelVariables if v.variability == "constant"}
    T, L = constant["sample_period"], constant["latency"]  # s
    t = np.arange(len(position)) * T
    signals = np.rec.fromarrays([t, position, scheduling], names=["time", "position", "scheduling"])
    t0 = time.perf_counter()
    res = simulate_fmu(str(fmu_path), input=signals, output=["torque"],
                       step_size=float(md.defaultExperiment.stepSize), output_interval=T,
                       stop_time=t[-1] + L + T)
    rate = len(position) / (time.perf_counter() - t0)
    shift = int(round((L + T) / T))  # the value recorded at t_k + L + T is the torque of sample k
    return res["torque"][shift:shift + len(position)], rate, L

def run(outdir) -> int:
    """The nine steps above into the folder ``outdir``, printing as it goes; returns 0.
    Takes about 40 s (tests/test_examples.py runs it: the held-out VAF within 1.5 points of
    the noise ceiling, K(theta) within 10 %, the improve loop finding the hidden effect)."""
    import matplotlib.pyplot as plt

    from . import plotting
    from .io import load_identification_data
    from .identification.identify import LPVPCEstimator
    from .models.model import vaf
    from .simulation.simulate import SubjectParams, write_dataset

    t_start = time.perf_counter()
    outdir = Path(outdir)
    figdir = outdir / "figures"
    figdir.mkdir(parents=True, exist_ok=True)

    _section("1. Virtual subject")
    t0 = time.perf_counter()
    paths = write_dataset(outdir / "data", seed=0, fs_out=1000.0)
    truth = json.loads(Path(paths["truth"]).read_text())
    params = SubjectParams(**truth["params"])
    m_id = truth["ident"]["measured"]
    _say(f"two 2-minute PT/UT pairs at 1 kHz (identification: multilevel trajectory; novel: ramps, "
         f"sines, slow walks), SNR {truth['ident']['snr_db']:g} dB, written to {outdir / 'data'} "
         f"[{time.perf_counter() - t0:.1f} s]")
    _say(f"identification trajectory spans {m_id['scheduling_range'][0]:+.3f}..{m_id['scheduling_range'][1]:+.3f} rad")

    _section("2. Identification (ident_PT.csv, ident_UT.csv -> 100 Hz)")
    ident = load_identification_data(pt=paths["ident_PT"], ut=paths["ident_UT"])
    t0 = time.perf_counter()
    model = LPVPCEstimator().fit(ident).model_
    t_fit = time.perf_counter() - t0
    model.conventions.setdefault("position_unit", "rad")
    model.conventions.setdefault("torque_sign", 1.0)
    model.save(outdir / "model.json")
    lo, hi = model.scheduling_range
    _say(f"{ident.n} samples at {ident.fs:g} Hz identified in {t_fit:.2f} s; reflex state order "
         f"{model.state_order}; identified position range {lo:+.3f}..{hi:+.3f} rad")
    _say(f"VAF on the identification data: {model.fit['vaf']:.2f} %")
    _say(f"model saved: {outdir / 'model.json'}")

    _section("3. Prediction of the novel (held-out) trajectory")
    novel = load_identification_data(pt=paths["novel_PT"], ut=paths["novel_UT"], target_fs=model.fs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", OutOfRangeWarning)
        pred = model.predict(novel.position, novel.scheduling)
    for w in caught:
        _say(f"note: {w.message}")
    clean = _perturbation_truth(paths["truth_novel"], model.fs)
    v_novel = vaf(novel.torque, pred.total)
    v_ceiling = vaf(novel.torque, clean["total"])
    _say(f"VAF novel trajectory:  {v_novel:6.2f} %   (two-sided IRF, offline)")
    _say(f"noise ceiling:         {v_ceiling:6.2f} %   (true noise-free torque vs the same noisy record)")
    _say(f"gap to the ceiling:    {v_ceiling - v_novel:6.2f} percentage points")
    _say(f"intrinsic torque vs true intrinsic torque: VAF {vaf(clean['intrinsic'], pred.intrinsic):.2f} %; "
         f"reflex vs true reflex: VAF {vaf(clean['reflex'], pred.reflex):.2f} %")

    _section("4. Recovered physiology vs truth")
    rho = _central_positions(model, N_TABLE_POSITIONS)
    K, K_true = model.elastic_stiffness(rho), params.K(rho)
    G, th = model.reflex_gain_threshold(rho)
    G_true, th_true = params.reflex_gain(rho), params.reflex_threshold(rho)
    err_K = 100 * (K / K_true - 1)
    _say(f"elastic stiffness K over the central {CENTRAL_FRACTION:.0%} of the identified range (N m/rad):")
    _say(f"  {'position (rad)':>15} {'K identified':>13} {'K true':>9} {'error':>8}")
    for r, k, kt, e in zip(rho, K, K_true, err_K):
        _say(f"  {r:>+15.3f} {k:>13.1f} {kt:>9.1f} {e:>+7.1f} %")
    _say(f"  worst |error| {np.max(np.abs(err_K)):.1f} %, median {np.median(np.abs(err_K)):.1f} %")
    _say()
    _say("reflex half-wave rectifier G * max(v - threshold, 0), fitted to the identified nonlinearity:")
    _say(f"  {'position (rad)':>15} {'gain':>7} {'true':>7} {'error':>8}   {'threshold':>9} {'true':>6} {'error':>8}")
    _say(f"  {'':>15} {'(N m s/rad)':>15} {'':>8}   {'(rad/s)':>9}")
    for r, g, gt, t, tt in zip(rho, G, G_true, th, th_true):
        _say(f"  {r:>+15.3f} {g:>7.2f} {gt:>7.2f} {100 * (g / gt - 1):>+7.1f} %   {t:>9.3f} {tt:>6.3f} "
             f"{100 * (t / tt - 1):>+7.1f} %")
    trend = lambda x: "rises" if x[-1] > x[0] else "falls"  # noqa: E731
    _say(f"  toward dorsiflexion the gain {trend(G)} (truth: {trend(G_true)}) and the threshold "
         f"{trend(th)} (truth: {trend(th_true)})")
    if not model.reflex_threshold_biased:
        _say("  (nonlinearity identified on the files' 1 kHz delayed velocity; over 30 seeds the gain trend is\n"
             "   within 20 % on 30, the threshold trend the least certain: the documentation's results page)")
    else:
        _say("  (nonlinearity identified on the 100 Hz delayed velocity, the default: the threshold trend is biased;\n"
             "   identify(..., high_rate_reflex=True) uses the files' 1 kHz velocity; see the documentation's results page)")
    _say(f"  reflex dynamics: order {model.state_order}, delay {1000 * model.delay / model.fs:.0f} ms "
         f"(truth: 2nd-order low-pass, wn {params.reflex_wn:g} rad/s, zeta {params.reflex_zeta:g}, "
         f"delay {1000 * params.reflex_delay:.0f} ms)")

    _section("5. Figures")
    t0 = time.perf_counter()
    curves = truth["curves"]
    figures = {
        "fig3_torque.png": lambda: plotting.plot_torque_fit(
            novel.time, novel.torque, pred, fig=plt.figure(figsize=(9, 6.5)), window=(20.0, 30.0)),
        "fig4_intrinsic_gain.png": lambda: plotting.plot_intrinsic_gain(model, plt.figure(figsize=(7, 5)).gca()),
        "fig5a_reflex_nonlinearity.png": lambda: plotting.plot_reflex_nonlinearity(
            model, plt.figure(figsize=(7, 5)).gca(), truth=params),
        "fig5b_reflex_irf.png": lambda: plotting.plot_reflex_irf(model, plt.figure(figsize=(7, 5)).gca(), truth=params),
        "stiffness_vs_truth.png": lambda: plotting.plot_stiffness_vs_truth(
            model, curves["theta"], curves["K"], plt.figure(figsize=(7, 5)).gca()),
    }
    for name, draw in figures.items():
        fig = draw()
        fig.tight_layout()
        fig.savefig(figdir / name, dpi=110)
        plt.close(fig)
    _say(f"{', '.join(figures)} in {figdir} [{time.perf_counter() - t0:.1f} s]")

    _section("6. Export")
    fmu_path = None
    try:
        from .export import exporter as export
    except ModuleNotFoundError as exc:
        if exc.name != f"{__package__}.export":
            raise
        _say("lpvpc.export.exporter is not available in this installation: skipped")
    else:
        t0 = time.perf_counter()
        export.export_casadi(model, outdir / "model.casadi")
        _say(f"CasADi step function: {outdir / 'model.casadi'} [{time.perf_counter() - t0:.2f} s]")
        t0 = time.perf_counter()
        # what `lpvpc export --fmu` makes: inputs position and scheduling only, derivatives inside
        fmu_path = export.export_fmu(model, outdir / "model.fmu", variant="sampled")
        _say(f"FMU (FMI 2.0 co-simulation, inputs position and scheduling): {fmu_path} "
             f"[{time.perf_counter() - t0:.2f} s]")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfRangeWarning)
            causal = model.predict(novel.position, novel.scheduling, causal=True)
        y, rate, latency = _run_fmu(fmu_path, novel.position, novel.scheduling)
        diff = np.max(np.abs(y - causal.total)) / np.max(np.abs(causal.total))
        _say(f"FMU run with fmpy.simulate_fmu as the README shows ({novel.n} samples, 1-ms steps, "
             f"{rate:,.0f} samples/s; declared latency {latency * 1e3:.0f} ms):")
        _say(f"  VAF {vaf(novel.torque, y):.2f} % (offline two-sided prediction {v_novel:.2f} %); "
             f"max |FMU - causal numpy| / max |torque| = {diff:.1e}")

    report = _validate(outdir, paths, fmu_path, v_ceiling)
    improve_report = _improve(outdir)
    loop_report = _closed_loop(outdir, model, paths, params) if fmu_path is not None else None

    _say()
    _say(f"done in {time.perf_counter() - t_start:.1f} s; outputs in {outdir}")
    if report is not None:
        _say(f"validation report: {report.resolve()} (open it in a browser)")
    _say(f"improve report: {improve_report.resolve()}")
    if loop_report is not None:
        _say(f"closed-loop report: {loop_report.resolve()}")
    return 0


HIDDEN_EFFECT = "direction_dependent_stiffness"


def _improve(outdir):
    """Step 8: the improve loop on a hidden-effect data set; returns the report's path."""
    from .io import load_identification_data
    from .diagnosis.improve import improve, write_report
    from .simulation.simulate import EFFECTS, write_dataset

    _section("8. What is the model missing? The improve loop on data with a hidden effect")
    t0 = time.perf_counter()
    paths = write_dataset(outdir / "data_hidden", seed=0, fs_out=1000.0, effects=(HIDDEN_EFFECT,))
    _say(f"virtual subject with a hidden effect ({EFFECTS[HIDDEN_EFFECT][0]}) written to {outdir / 'data_hidden'}; "
         f"the loop is not told which")
    ident = load_identification_data(pt=paths["ident_PT"], ut=paths["ident_UT"])
    held = load_identification_data(pt=paths["novel_PT"], ut=paths["novel_UT"], target_fs=ident.fs)
    _say(f"  {'step':>4}  {'model':34} {'held-out VAF':>12} {'RMSE (N m)':>11}")

    def show(r):
        note = "" if r.kept else "  (not kept: no held-out gain)"
        _say(f"  {r.index:>4}  {r.label[:34]:34} {r.heldout_vaf:>10.2f} % {r.heldout_rmse:>11.4f}{note}")
        if r.kept and r.diagnosis is not None:
            _say(f"        diagnosis: {r.diagnosis.answer().split('. ')[0].rstrip('.')}.")

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        ladder = improve(ident, held, progress=show)
        path = write_report(ladder, held, outdir / "improve")
    first, last = ladder.rungs[0], ladder.final
    _say(f"stopped: {ladder.stopped}")
    _say(f"held-out error: VAF {first.heldout_vaf:.2f} % -> {last.heldout_vaf:.2f} %, RMSE {first.heldout_rmse:.4f} -> "
         f"{last.heldout_rmse:.4f} N m ({100 * (1 - last.heldout_rmse / first.heldout_rmse):.0f} % lower) "
         f"[{time.perf_counter() - t0:.1f} s]")
    return path


def _closed_loop(outdir, model, paths, params):
    """Step 9: the closed-loop form of the whole-joint model in a compliant exoskeleton loop, beside the
    virtual subject and the replay FMU; returns the page's path."""
    from lpvpc.validation.closed_loop import evaluate_closed_loop, write_closed_loop_report

    from .export.closed_loop import distillation_trial, fit_closed_loop
    from .io import load_trial
    from .export.whole_joint import fit_whole_joint

    _section("9. Closed loop: the ankle model's torque moves the foot")
    t0 = time.perf_counter()
    ut = load_trial(paths["ident_UT"])
    whole = fit_whole_joint(model, ut)
    cl = fit_closed_loop(whole, [distillation_trial(whole, ut)])
    _say(f"closed-loop form (angle and angular velocity in, torque out, no latency beyond the reflex delay): "
         f"declared inertia {cl.inertia:.4f} kg m^2 for the plant (truth {params.inertia:g})")
    metrics, traces = evaluate_closed_loop(cl, outdir / "closed_loop", duration=20.0, params=params)
    for g in metrics["gains"]:
        r = g["closed_loop"]["1 ms"]
        rep = g["replay"]
        model_run = (f"angle deviation VAF {r['deviation']:.2f} %, torque {r['torque']:.2f} % vs the subject"
                     if r["stable"] else f"diverged at {r['diverged_at']:.2f} s")
        replay_run = "stable" if rep["stable"] else f"diverges at {rep['diverged_at']:.2f} s"
        _say(f"  Kp {g['kp']:>5g} N m/rad: closed-loop FMU {model_run}; replay FMU (40 ms latency) {replay_run}")
    path = write_closed_loop_report(outdir / "closed_loop", metrics, traces)
    _say(f"page and figure in {outdir / 'closed_loop'} [{time.perf_counter() - t0:.1f} s]")
    return path


def _validate(outdir, paths, fmu_path, v_ceiling):
    """Step 7: the validation harness on the novel record; returns the report's path."""
    _section("7. Validation on the novel trajectory (prediction routes, co-simulation with the actuator)")
    try:
        from lpvpc.validation import validate
        from lpvpc.validation.compare import worst_route_difference
    except ModuleNotFoundError as exc:
        if exc.name != "validation":
            raise
        _say("the validation package is not available in this installation: skipped")
        return None
    if fmu_path is None:
        _say("no model FMU was exported: skipped")
        return None
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        # the default: the exact model FMU (the identified model; its latency removed when comparing)
        res = validate(outdir / "model.json", paths["novel_PT"], paths["novel_UT"], outdir / "validation",
                       command_line=f"python -m lpvpc.demo {outdir}")
    m = res.metrics
    c = m["cosim"]
    ag = m["route_agreement"]
    _say(f"VAF offline {m['vaf']:.2f} %, FMU replay {m['vaf_fmu']:.2f} %, co-simulation {m['vaf_cosim']:.2f} %  "
         f"(noise ceiling {v_ceiling:.2f} %)")
    worst = worst_route_difference(ag)
    _say(f"CasADi and FMU routes agree with numpy to {worst:.1e} of the torque scale (exact model FMU, latency "
         f"{c['model_fmu_latency_samples']} samples removed; the causal closed-loop form: {m['vaf_causal']:.2f} % "
         f"offline)")
    cal = c["calibration"]
    if cal.get("done"):
        _say(f"actuator servo calibrated on the record: {cal['servo_bandwidth']:.2f} Hz, damping "
             f"{cal['servo_damping']:.3f} (position fit VAF {cal['vaf']:.3f} %)")
    le = c["load_effect"] or {}
    coupling = (f"the exact FMU's output, {c['model_fmu_latency_samples']} steps late"
                if c["model_fmu_variant"] == "exact" else
                f"'{c['settings']['coupling']}' (mean {c['iterations']['mean']:.1f} iterations)")
    _say(f"co-simulation: {c['actuator_steps_per_model_step']} actuator steps of {1e3 * c['step_actuator_s']:g} ms per "
         f"{1e3 * c['step_model_s']:g} ms model step, load torque: {coupling}; {c['real_time_factor']:.0f}x real time; "
         f"the load moves the perturbation by at most {le.get('perturbation_position_max_mrad', float('nan')):.2f} mrad")
    s = m["scheduling"]
    _say(f"{100 * s['out_of_range_fraction']:.1f} % of the record lies outside the identified range (offline RMSE "
         f"there {s['out_of_range']['numpy']['rmse']:.3f} N m vs {s['in_range']['numpy']['rmse']:.3f} N m inside)")
    _say(f"report, metrics.json and figures in {res.report_dir} [{time.perf_counter() - t0:.1f} s]")
    return res.files["report"]


def main(argv=None) -> int:
    """The command line ``python -m lpvpc.demo [OUTDIR]`` (what ``make demo`` runs): the
    steps of :func:`run` into OUTDIR (default demo_out), the package's warnings printed as
    lines; returns the exit status (an error: one line on stderr).

    >>> try:  # doctest: +ELLIPSIS
    ...     main(["--help"])
    ... except SystemExit as exc:
    ...     print("exit status", exc.code)
    usage: python -m lpvpc.demo [-h] [outdir]
    ...
    exit status 0
    """
    parser = argparse.ArgumentParser(prog="python -m lpvpc.demo", description=__doc__.splitlines()[0])
    parser.add_argument("outdir", nargs="?", default="demo_out", help="output folder (default demo_out)")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", UnitWarning)
            original = warnings.showwarning

            def show(message, category, *rest, **kw):
                if issubclass(category, LpvpcWarning):  # the package's notes: a line, not a source line
                    print(f"warning: {message}", flush=True)
                else:
                    original(message, category, *rest, **kw)

            warnings.showwarning = show
            return run(args.outdir)
    except LpvpcError as exc:
        print(f"demo: error: {exc}", file=sys.stderr)
        return exc.exit_status


if __name__ == "__main__":
    sys.exit(main())
