"""Sphinx extension: write benchmarks.md from benchmarks/results/*.txt before the build.

Each recorded table is shown as it was written (a text block, so its own layout stays),
under the command that reproduces it. A results file that no command below knows and whose
name matches no ``benchmarks/bench_<name>.py`` is a build warning (an error under -W), so a
new benchmark cannot appear without saying how to reproduce it.
"""

from pathlib import Path

from sphinx.util import logging

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = ROOT / "benchmarks" / "results"
PAGE = HERE / "benchmarks.md"  # generated, git-ignored
REAL = "LPVPC_REAL_DATA=/path/to/recordings "  # the lab's public recordings (skipped when absent)

# results file -> (what it measures, command that reproduces it)
TABLES = {
    "montecarlo.txt": ("Accuracy on the virtual subject over 20 noise seeds",
                       "python benchmarks/bench_montecarlo.py 20"),
    "uncertainty.txt": ("Coverage of the 95 % confidence intervals, 1 kHz files",
                        "nice python benchmarks/bench_uncertainty.py 20"),
    "uncertainty_100hz_files.txt": ("Coverage of the 95 % confidence intervals, 100 Hz files",
                                    "nice python benchmarks/bench_uncertainty.py 20 --files-fs 100"),
    "reflex_observability.txt": ("What a 100 Hz record can show of the reflex rectifier",
                                 "python benchmarks/bench_reflex_observability.py"),
    "reflex_1k.txt": ("Reflex gain and threshold trends from 1 kHz and 100 Hz files",
                      "python benchmarks/bench_reflex_1k.py"),
    "reflex_1k_seeds10-19.txt": ("Reflex gain and threshold trends from 1 kHz files, seeds 10-19 (not tuned on)",
                                 "python benchmarks/bench_reflex_1k.py 10 10"),
    "reflex_1k_seeds20-29.txt": ("Reflex gain and threshold trends from 1 kHz files, seeds 20-29 (not tuned on)",
                                 "python benchmarks/bench_reflex_1k.py 10 20"),
    "diagnose_significance.txt": ("Significance rules of the diagnosis compared on the same fits",
                                  "python benchmarks/bench_diagnose.py --rules <dumps of --dump runs>"),
    "reflex_1k_bias.txt": ("Where the 1 kHz reflex bias came from (noise-free records)",
                           "python benchmarks/bench_reflex_1k_bias.py"),
    "threshold_information.txt": ("How much a record holds about the reflex threshold's trend",
                                  "python benchmarks/bench_threshold_information.py"),
    "threshold_alternatives.txt": ("Reflex threshold intervals: the shipped rule and the others tried",
                                   "nice python benchmarks/bench_threshold_alternatives.py 40"),
    "lab_perturbation.txt": ("The virtual subject under the lab's perturbation design",
                             "python benchmarks/bench_lab_perturbation.py"),
    "real_pilot.txt": ("The lab's pilot LPV trial, held-out last 30 %",
                       REAL + "python benchmarks/bench_real_pilot.py"),
    "real_stationary.txt": ("The lab's five stationary trials, held-out last 30 %",
                            REAL + "python benchmarks/bench_real_stationary.py"),
    "stationary_no_ut.txt": ("Stationary trials: PT alone against the PT/UT pair",
                             "python benchmarks/bench_stationary_no_ut.py"),
    "trials.txt": ("Several trials in one identification", "python benchmarks/bench_trials.py 3"),
    "identify.txt": ("Identification speed and memory", "python benchmarks/bench_identify.py"),
    "identify_long.txt": ("Long records: whole process and peak memory, 2 to 30 minutes",
                          "python benchmarks/bench_identify.py --long"),
    "selection.txt": ("Structure selection by cross-validation on the lab's pilot trial",
                      REAL + "python benchmarks/bench_selection.py"),
    "forward_selection.txt": ("Structure selection scored forward in time, the lab's pilot trial over five splits",
                              REAL + "nice python benchmarks/bench_forward_selection.py"),
    "forward_selection_subjects.txt": ("Structure selection's choice rule before and after, the virtual subject",
                                       "nice python benchmarks/bench_forward_selection.py --subjects"),
    "closed_loop.txt": ("The closed-loop form in a compliant exoskeleton loop",
                        "python benchmarks/bench_closed_loop.py"),
    "mujoco.txt": ("The closed-loop ankle model in a MuJoCo exoskeleton loop: real-time factor",
                   "python benchmarks/bench_mujoco.py"),
    "population.txt": ("A population of virtual subjects: identification and K bands over draws",
                       "python benchmarks/bench_population.py 90 --first-seed 100"),
    "population_record.txt": ("A population of virtual subjects: identification on the record seeds",
                              "python benchmarks/bench_population.py 90 --record"),
    "population_diagnosis.txt": ("A population of virtual subjects: diagnosis and the improve ladder over draws",
                                 "python benchmarks/bench_population_diagnosis.py"),
    "population_diagnosis_record.txt": ("A population of virtual subjects: diagnosis on the record seeds",
                                        "python benchmarks/bench_population_diagnosis.py --record"),
    "diagnosis_oracle.txt": ("The diagnosis's oracle: what any rule could name over the population",
                             "python benchmarks/bench_diagnosis_oracle.py"),
    "diagnosis_oracle_record.txt": ("The diagnosis's oracle on the record seeds",
                                    "python benchmarks/bench_diagnosis_oracle.py --jobs 2 --record"),
    "population_significance_rules.txt": ("Diagnosis significance rules replayed on the population's candidates",
                                          "python benchmarks/population_significance_rules.py"),
    "population_diagnosis_profile.txt": ("A population diagnosis draw, profiled",
                                         "python benchmarks/bench_population_diagnosis.py --profile reflex_habituation"),
    "real_stationary_physiology.txt": ("The lab's stationary trials through the documented command",
                                       "python benchmarks/bench_real_stationary_physiology.py"),
    "study.txt": ("A study: group differences over virtual cohorts, speed-up with workers",
                  "python benchmarks/bench_study.py --cohorts 10 --null-cohorts 4 --subjects 24 --duration 60"),
    "bounded_loading.txt": ("Bounded loaders: files declaring huge unrelated variables",
                            "python benchmarks/bench_bounded_loading.py"),
    "identify_floor.txt": ("Identification against a bare least-squares solve",
                           "python benchmarks/bench_identify.py --floor"),
    "export.txt": ("Export: code generation, FMU replay, CasADi", "python benchmarks/bench_export.py"),
    "fmu_cycles.txt": ("FMU lifecycle: instantiate/reset/free cycles and memory",
                       "python benchmarks/bench_fmu_cycles.py"),
    "fmu_me.txt": ("Model Exchange FMUs", "python benchmarks/bench_fmu_me.py"),
    "portable_ssp.txt": ("The portable SSP in libcosim and ECOS", "python benchmarks/bench_portable_ssp.py"),
    "validation.txt": ("Validation: offline, FMU replay and co-simulation",
                       "python benchmarks/bench_validation.py"),
    "whole_joint.txt": ("Whole-joint model", "python benchmarks/bench_whole_joint.py"),
    "diagnose.txt": ("Diagnosis of hidden effects on the virtual subject",
                     "nice python benchmarks/bench_diagnose.py"),
    "diagnose_lab_pulses.txt": ("Diagnosis under the lab's perturbation design",
                                "nice python benchmarks/bench_diagnose.py --perturbation lab_pulses --seeds 20,5"),
    "diagnose_prbs.txt": ("Diagnosis under a PRBS perturbation without quiet windows",
                          "nice python benchmarks/bench_diagnose.py --perturbation prbs --seeds 20,5"),
    "diagnose_activation.txt": ("Why an activation effect falls short: the activation estimate",
                                "python benchmarks/bench_diagnose.py --activation-why --seeds 0,5"),
    "diagnose_relaxation.txt": ("Why a PRBS design hides stress relaxation",
                                "python benchmarks/bench_diagnose.py --relaxation-why"),
    "diagnose_speed.txt": ("Diagnosis speed", "python benchmarks/bench_diagnose.py --speed"),
    "blas_threads.txt": ("Diagnosis in a Python session: BLAS threads", "env -u OPENBLAS_NUM_THREADS python benchmarks/bench_blas_threads.py"),
    "gain_identifiability.txt": ("Why a PRBS record does not determine the reflex gain: the model-rate path's reading", "python benchmarks/bench_gain_identifiability.py 90"),
    "friction_rate.txt": ("Friction features at the file's rate or the model's; the lab's position noise floor",
                          "LPVPC_REAL_DATA=/path/to/recordings nice python benchmarks/bench_friction_rate.py"),
    "fuzz_model.txt": ("Fuzzing the model-file loader", "python benchmarks/bench_fuzz_model.py"),
    "effect_size.txt": ("Torque each simulated effect carries, per perturbation design",
                        "python benchmarks/bench_effect_size.py 3"),
    "reflex_dynamics_range_prbs.txt": ("Reflex dynamics changing ninefold: what the improve ladder missed",
                                       "python benchmarks/bench_reflex_dynamics_range.py --seeds 0,5"),
    "relaxed_stiffness.txt": ("Intervals of a model with stress relaxation",
                              "nice python benchmarks/bench_relaxed_stiffness.py 20"),
    "relaxed_stiffness_causes.txt": ("Stress relaxation on a relaxing subject: causes of the K bias",
                                     "nice python benchmarks/bench_relaxed_stiffness.py --causes 0,1,2,3"),
    "relaxed_stiffness_real.txt": ("Stress relaxation's time on the lab's stationary trials (real data)",
                                   "LPVPC_REAL_DATA=../shared/real nice python benchmarks/bench_relaxed_stiffness.py --real"),
}


def _entry(path: Path, logger):
    if path.name in TABLES:
        return TABLES[path.name]
    script = ROOT / "benchmarks" / f"bench_{path.stem}.py"
    if not script.exists():
        logger.warning(f"benchmarks/results/{path.name}: no command known to reproduce it "
                       f"(add it to TABLES in docs/results_page.py)")
    return path.stem.replace("_", " ").capitalize(), f"python benchmarks/bench_{path.stem}.py"


def write_page(app) -> None:
    logger = logging.getLogger(__name__)
    files = sorted(RESULTS.glob("*.txt"))
    order = {name: i for i, name in enumerate(TABLES)}
    files.sort(key=lambda p: (order.get(p.name, len(order)), p.name))
    out = ["# Benchmark tables", "",
           "Every table below is the file `benchmarks/results/NAME.txt` as the benchmark wrote it, "
           "under the command that reproduces it (run from a checkout, in the project venv: "
           "`make bench` runs them all). Timings come from a shared 2-core machine: compare the "
           "ratios measured within one run, not the absolute times. What the figures mean is on "
           "the [results](results.md) page.", ""]
    for path in files:
        title, command = _entry(path, logger)
        text = path.read_text(encoding="utf-8").rstrip("\n")
        fence = "`" * max(3, max((len(run) for run in text.split() if set(run) == {"`"}), default=0) + 1)
        out += [f"## {title}", "", f"`{path.name}`, reproduced by:", "", "```sh", command, "```", "",
                fence + "text", text, fence, ""]
    content = "\n".join(out)
    if not PAGE.exists() or PAGE.read_text(encoding="utf-8") != content:  # keep incremental builds quiet
        PAGE.write_text(content, encoding="utf-8")


def setup(app):
    app.connect("builder-inited", write_page)
    return {"parallel_read_safe": True}
