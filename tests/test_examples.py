"""Every public function and class has an example (issue 13): a doctest in its docstring
(run by ``pytest --doctest-modules`` for lpvpc, and below for lpvpc.validation, which lives
outside the lpvpc folder), or an example test that does what a user does with it.

The public API is ``lpvpc.__all__`` plus, for every public module of lpvpc and
lpvpc.validation, its ``__all__``, or, where a module has none, every function and class
it defines whose name does not start with an underscore. ``REGISTRY`` names the example
test of each name without a doctest (a test elsewhere in tests/, or one of the example
tests in this file, marked with ``@example_of``). ``PENDING`` lists the names that still
have neither: it may only shrink, and a new public name without an example fails.
"""

import ast
import doctest
import functools
import importlib
import inspect
import pkgutil
from pathlib import Path

import pytest

import lpvpc
import lpvpc.validation

TESTS = Path(__file__).resolve().parent

#: public name -> "test_file.py::test_function" that shows its use (tests elsewhere; the
#: test's body or the fixtures it requests must use the object)
REGISTRY = {
    "lpvpc.identification.identify.time_base_problem": "test_lab_workflow.py::test_time_base_too_fast_is_named",
    "lpvpc.export.actuator.actuator_build_kwargs": "test_fmu_build.py::test_guid_is_a_hash_of_sources_and_settings",
    "lpvpc.export.actuator.build_actuator_fmu": "test_actuator.py::test_build_is_cached",
    "lpvpc.export.actuator.actuator_source_dir": "test_fmu_build.py::test_guid_is_a_hash_of_sources_and_settings",
    "lpvpc.cli.main": "test_cli.py::test_export",
    "lpvpc.cli.validate.run": "test_validation.py::test_min_vaf_failing_exits_1",
    "lpvpc.io.trial.Trial": "test_data.py::test_degree_conversion",
    "lpvpc.models.effects.model_reflex_delay_steps": "test_effects.py::test_reflex_delay_entry_reruns_the_models_reflex_at_neighbouring_delays",
    "lpvpc.io.trial.write_trial_csv": "test_data.py::test_csv_round_trip",
    "lpvpc.io.trial.check_trial": "test_data.py::test_uneven_time_named",
    "lpvpc.io.readers.load_trial": "test_matfiles.py::test_nldat_trial_read_by_variable",
    "lpvpc.io.decimation.decimate_trial": "test_data.py::test_decimation_in_stages",
    "lpvpc.io.identification_data.PerturbationData": "test_data.py::test_perturbation_data_validates",
    "lpvpc.models.reflex.high_rate_input": "test_reflex_1k.py::test_high_rate_regressor_is_the_decimated_nonlinearity",
    "lpvpc.models.reflex.high_rate_drive": "test_reflex_1k.py::test_high_rate_regressor_is_the_decimated_nonlinearity",
    "lpvpc.io.identification_data.pair_trials": "test_simulate.py::test_pair_trials_reproduces_the_simulated_perturbation",
    "lpvpc.io.identification_data.load_perturbation_file": "test_data.py::test_load_perturbation_file_decimates",
    "lpvpc.io.identification_data.join_trials": "test_trials.py::test_join_trials_checks_rate_and_conventions",
    "lpvpc.io.identification_data.write_perturbation_csv": "test_data.py::test_perturbation_csv_round_trip_is_exact",
    "lpvpc.diagnosis.cv.BlockCV": "test_diagnose.py::test_block_cv_equals_explicit_least_squares",
    "lpvpc.diagnosis.cv.paired_test": "test_diagnose.py::test_paired_test",
    "lpvpc.models.effects.shifted_reflex_torques": "test_effects.py::test_reflex_delay_entry_reruns_the_models_reflex_at_neighbouring_delays",
    "lpvpc.diagnosis.surrogate.Surrogate": "test_diagnose.py::test_reflex_bursts_in_the_emg_do_not_leak_into_the_activation_feature",
    "lpvpc.diagnosis.candidates.signal_leaks": "test_diagnose.py::test_reflex_bursts_in_the_emg_do_not_leak_into_the_activation_feature",
    "lpvpc.diagnosis.report.write_report": "test_diagnose.py::test_diagnose_and_improve_reports_render_in_chromium",
    "lpvpc.models.effects.describe": "test_effects.py::test_catalog_entries_are_documented",
    "lpvpc.models.effects.check_effects": "test_effects.py::test_unknown_effects_are_refused",
    "lpvpc.models.effects.signals_from_data": "test_effects.py::test_extended_casadi_step_matches_numpy",
    "lpvpc.models.effects.background_emg": "test_diagnose.py::test_candidate_reading_a_leaking_signal_is_not_named",
    "lpvpc.models.effects.direction_alpha": "test_effects.py::test_direction_memory_latches_through_holds",
    "lpvpc.export.exporter.step_function": "test_export_casadi.py::test_step_interface",
    "lpvpc.export.exporter.state_layout": "test_export_casadi.py::test_step_interface",
    "lpvpc.export.exporter.latency_samples": "test_validation.py::test_exact_fmu_in_the_loop_loads_the_actuator_with_its_latency",
    "lpvpc.export.exporter.parameter_vector": "test_export_casadi.py::test_parameter_vector_and_names",
    "lpvpc.export.exporter.parameter_names": "test_export_casadi.py::test_parameter_vector_and_names",
    "lpvpc.export.exporter.parameter_info": "test_export_casadi.py::test_parameter_vector_and_names",
    "lpvpc.export.exporter.export_casadi": "test_effects.py::test_extended_casadi_step_matches_numpy",
    "lpvpc.export.exporter.trajectory_function": "test_export_casadi.py::test_saved_function_runs_with_casadi_alone",
    "lpvpc.export.exporter.replay_inputs": "test_effects.py::test_extended_fmu_takes_the_extra_channels_as_inputs",
    "lpvpc.export.exporter.export_fmu": "test_model_fmu.py::test_fmu_state_round_trips",
    "lpvpc.export.exporter.save_casadi": "test_casadi_files.py::test_save_casadi_writes_any_step_with_its_metadata",
    "lpvpc.export.exporter.load_casadi": "test_casadi_files.py::test_the_metadata_travels_with_the_function",
    "lpvpc.export.exporter.CasadiExport": "test_casadi_files.py::test_a_host_step_that_is_not_the_tick_is_refused",
    "lpvpc.export.exporter.build_step_fmu": "test_one_of_each.py::test_build_step_fmu_runs_the_step_it_was_given",
    "lpvpc.export.exporter.ticks_per_sample": "test_model_fmu.py::test_model_description",
    "lpvpc.export.exporter.fmu_parameter_name": "test_export_casadi.py::test_parameter_vector_and_names",
    "lpvpc.export.fmu_build.FmuVariable": "test_fmu_build.py::test_validation_of_a_system_without_parameters",
    "lpvpc.export.fmu_build.build_fmu": "test_fmu_build.py::test_validation_of_a_system_without_parameters",
    "lpvpc.export.fmu_build.fmi_headers_dir": "test_fmu_build.py::test_fmi_headers_dir",
    "lpvpc.export.fmu_build.fmu_guid": "test_fmu_build.py::test_guid_is_a_hash_of_sources_and_settings",
    "lpvpc.linalg.project_out_and_solve": "test_identify.py::test_projection_equals_literal_pseudo_inverse_formula",
    "lpvpc.diagnosis.improve.physiology": "test_newcomer.py::test_improve_report_shows_the_physiology_of_each_step_and_no_repository_paths",
    "lpvpc.diagnosis.improve.write_report": "test_diagnose.py::test_improve_report",
    "lpvpc.diagnosis.improve.Ladder": "test_diagnose.py::test_improve_report",
    "lpvpc.diagnosis.improve.Rung": "test_diagnose.py::test_improve_report",
    "lpvpc.cli.diagnose.run": "test_diagnose.py::test_cli_diagnose_and_improve",
    "lpvpc.cli.improve.run": "test_diagnose.py::test_cli_diagnose_and_improve",
    "lpvpc.io.matfiles.read_mat": "test_matfiles.py::test_real_lab_file_reads",
    "lpvpc.plotting.plot_torque_fit": "test_cli.py::test_plotting_functions_draw",
    "lpvpc.plotting.plot_intrinsic_gain": "test_cli.py::test_plotting_functions_draw",
    "lpvpc.plotting.plot_reflex_nonlinearity": "test_cli.py::test_plotting_functions_draw",
    "lpvpc.plotting.plot_reflex_irf": "test_cli.py::test_plotting_functions_draw",
    "lpvpc.plotting.plot_stiffness_vs_truth": "test_cli.py::test_plotting_functions_draw",
    "lpvpc.simulation.subject.SubjectParams": "test_simulate.py::test_K_curve_shape_and_values",
    "lpvpc.simulation.physics.servo": "test_simulate.py::test_servo_matches_analytic_step_response",
    "lpvpc.simulation.physics.reflex_torque": "test_simulate.py::test_reflex_is_a_half_wave_rectifier_with_unit_dc_gain",
    "lpvpc.identification.subspace.hankel_rows": "test_trials.py::test_moesp_hankel_rows_stay_inside_trials",
    "lpvpc.identification.subspace.streamed_r": "test_trials.py::test_moesp_hankel_rows_stay_inside_trials",
    "lpvpc.export.whole_joint.WholeJointModel": "test_whole_joint.py::test_cli_whole_joint_writes_model_and_fmu",
    "lpvpc.export.closed_loop.ClosedLoopModel": "test_closed_loop.py::test_errors_and_round_trip",
    "lpvpc.validation.closed_loop.evaluate_closed_loop": "test_closed_loop.py::test_validation_closed_loop_section",
    "lpvpc.validation.closed_loop.evaluate_loop_ssp": "test_closed_loop.py::test_loop_ssp_in_fmpy_and_libcosim",
    "lpvpc.validation.closed_loop.write_loop_ssp": "test_closed_loop.py::test_loop_ssp_in_fmpy_and_libcosim",
    "lpvpc.validation.closed_loop.run_loop_ssp_libcosim": "test_closed_loop.py::test_loop_ssp_in_fmpy_and_libcosim",
    "lpvpc.validation.closed_loop.run_loop_fmpy": "test_closed_loop.py::test_loop_ssp_in_fmpy_and_libcosim",
    "lpvpc.validation.closed_loop.exoskeleton_parameters": "test_closed_loop.py::test_loop_ssp_in_fmpy_and_libcosim",
    "lpvpc.validation.closed_loop.write_closed_loop_report": "test_closed_loop.py::test_validation_closed_loop_section",
    "lpvpc.validation.closed_loop.closed_loop_section": "test_closed_loop.py::test_validation_closed_loop_section",
    "lpvpc.export.closed_loop.ClosedLoopPrediction": "test_closed_loop.py::test_causal_form_costs_little_on_a_novel_trajectory",
    "lpvpc.export.closed_loop.distillation_trial": "test_closed_loop.py::test_inertia_stiffness_and_viscosity_against_the_subject",
    "lpvpc.export.closed_loop.fit_closed_loop": "test_closed_loop.py::test_inertia_stiffness_and_viscosity_against_the_subject",
    "lpvpc.export.closed_loop.export_closed_loop_casadi": "test_closed_loop.py::test_casadi_tick_function_file",
    "lpvpc.export.closed_loop.export_closed_loop_fmu": "test_closed_loop.py::test_tick_function_equals_numpy_at_samples_and_fmus_every_tick",
    "lpvpc.export.closed_loop.fit_perturbation_impedance": "test_closed_loop.py::test_perturbation_level_impedance_on_the_identification_data",
    "lpvpc.export.closed_loop.predict_perturbation_impedance": "test_closed_loop.py::test_perturbation_level_impedance_on_the_identification_data",
    "lpvpc.simulation.compliant_loop.FmuSource": "test_closed_loop.py::test_compliant_loop_stays_stable_and_follows_the_subject",
    "lpvpc.simulation.compliant_loop.LoopRun": "test_closed_loop.py::test_compliant_loop_stays_stable_and_follows_the_subject",
    "lpvpc.simulation.compliant_loop.LoopSetup": "test_closed_loop.py::test_compliant_loop_stays_stable_and_follows_the_subject",
    "lpvpc.simulation.compliant_loop.VirtualSubject": "test_closed_loop.py::test_compliant_loop_stays_stable_and_follows_the_subject",
    "lpvpc.simulation.compliant_loop.highpass": "test_closed_loop.py::test_compliant_loop_stays_stable_and_follows_the_subject",
    "lpvpc.simulation.compliant_loop.loop_vaf": "test_closed_loop.py::test_compliant_loop_stays_stable_and_follows_the_subject",
    "lpvpc.simulation.compliant_loop.reference_trajectory": "test_closed_loop.py::test_compliant_loop_stays_stable_and_follows_the_subject",
    "lpvpc.simulation.compliant_loop.run_loop": "test_closed_loop.py::test_compliant_loop_stays_stable_and_follows_the_subject",
    "lpvpc.export.whole_joint.fit_whole_joint": "test_whole_joint.py::test_validation_report_has_a_whole_joint_section",
    "lpvpc.export.whole_joint.export_whole_joint_casadi": "test_whole_joint.py::test_casadi_step_and_fmus_agree_with_numpy",
    "lpvpc.export.whole_joint.export_whole_joint_fmu": "test_whole_joint.py::test_casadi_step_and_fmus_agree_with_numpy",
    "lpvpc.export.whole_joint.latency_samples": "test_whole_joint.py::test_casadi_step_and_fmus_agree_with_numpy",
    "lpvpc.validation.cosim.CosimSettings": "test_ssp.py::test_connections_match_the_fmus_and_the_master",
    "lpvpc.validation.cosim.run_cosimulation": "test_validation.py::test_fmi3_cosimulation_equals_fmi2_and_couplings_agree",
    "lpvpc.validation.cosim.connections": "test_ssp.py::test_connections_match_the_fmus_and_the_master",
    "lpvpc.validation.engines.available": "test_ssp.py::test_portable_ssp_runs_in_libcosim_and_ecos_like_the_harness",
    "lpvpc.validation.engines.run_portable_ssp": "test_ssp.py::test_portable_ssp_runs_in_libcosim_and_ecos_like_the_harness",
    "lpvpc.validation.fmu.inspect_fmu": "test_validation.py::test_exact_fmu_in_the_loop_loads_the_actuator_with_its_latency",
    "lpvpc.validation.fmu.FMUInstance": "test_ssp.py::test_fmpy_runs_the_ssp_like_the_harness",
    "lpvpc.validation.harness.load_record": "test_ssp.py::test_validate_report_writes_the_ssp",
    "lpvpc.validation.ssp.write_ssp": "test_ssp.py::test_validate_report_writes_the_ssp",
    "lpvpc.validation.ssp.instance_parameters": "test_ssp.py::test_validate_report_writes_the_ssp",
    "lpvpc.validation.whole_joint.fmu_replay": "test_whole_joint.py::test_casadi_step_and_fmus_agree_with_numpy",
    "lpvpc.study.StudyResult": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.manifest.ManifestRow": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.report.report_html": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.run.analyse_record": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.run.execute": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.run.record_key": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.run.diagnosis_summary": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.tables.common_grid": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.tables.group_rows": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.tables.records_rows": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.tables.write_csv": "test_study.py::test_the_study_pieces_by_hand_give_the_study_tables",
    "lpvpc.study.run_study": "test_study.py::test_bad_records_are_named_and_the_others_finish",
    "lpvpc.study.cohort.write_cohort": "test_study.py::test_a_within_subject_design_is_compared_in_pairs",
    "lpvpc.study.manifest.ManifestError": "test_study.py::test_bad_manifest_is_one_line_naming_row_and_column",
    "lpvpc.study.manifest.read_manifest": "test_study.py::test_manifest_reads_settings_and_paths_relative_to_it",
}

#: public names without an example yet (may only shrink)
PENDING = {"lpvpc.cli.study.run"}

#: example tests in this file: public name -> "test_examples.py::test_function"
EXAMPLES = {}


def example_of(*names):
    """Register the decorated test as the example of ``names`` (qualified public names)."""

    def mark(fn):
        for name in names:
            EXAMPLES[name] = f"{Path(__file__).name}::{fn.__name__}"
        return fn

    return mark


def public_modules():
    """Every public module of lpvpc and of its subpackages (the C source folder aside)."""
    for info in pkgutil.walk_packages(lpvpc.__path__, prefix="lpvpc."):
        if not any(part.startswith("_") for part in info.name.split(".")) and info.name != "lpvpc.export.c":
            yield importlib.import_module(info.name)


def public_api() -> dict:
    """{qualified name: object} of every public function and class."""
    # (a top-level name re-exported from a module is checked under that module's name)
    api = {f"lpvpc.{n}": v for n in lpvpc.__all__ if getattr(v := getattr(lpvpc, n), "__module__", "lpvpc") == "lpvpc"}
    for mod in public_modules():
        if hasattr(mod, "__all__"):
            names = list(mod.__all__)
            if Path(mod.__file__).name == "__init__.py":  # a subpackage's re-exports: checked where defined
                names = [n for n in names if getattr(getattr(mod, n), "__module__", mod.__name__) == mod.__name__]
        else:
            names = [n for n, v in vars(mod).items()
                     if not n.startswith("_") and getattr(v, "__module__", None) == mod.__name__]
        api.update({f"{mod.__name__}.{n}": getattr(mod, n) for n in names})
    return {k: v for k, v in api.items() if inspect.isfunction(v) or inspect.isclass(v)}


def has_doctest(obj) -> bool:
    """A ``>>>`` example in the docstring (of a class: or of one of its own methods)."""
    docs = [obj.__doc__ or ""]
    if inspect.isclass(obj):
        docs += [getattr(v, "__doc__", None) or "" for k, v in vars(obj).items()
                 if callable(v) or isinstance(v, (property, classmethod, staticmethod))]
    return any(">>>" in d for d in docs)


def _import(name):
    try:
        return importlib.import_module(name)
    except ImportError:
        return None


@functools.lru_cache(maxsize=None)
def _functions(path: Path) -> tuple:
    tree = ast.parse(path.read_text())
    return tree, {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}


def objects_used(path: Path, test: str):
    """ids of the objects a module-level test function of ``path`` refers to, in its body
    or in the fixtures it requests (of its file or tests/conftest.py), resolved through
    the file's and the functions' imports (None: no such test)."""
    tree, defs = _functions(path)
    fixtures = {**_functions(TESTS / "conftest.py")[1], **defs}
    fn = defs.get(test)
    if fn is None:
        return None
    bodies, todo = [], [fn]
    while todo:  # the test and, transitively, the fixtures it requests
        f = todo.pop()
        if f in bodies:
            continue
        bodies.append(f)
        todo += [fixtures[a.arg] for a in f.args.args if a.arg in fixtures]
    nodes = [n for f in bodies for n in ast.walk(f)]
    names = {}
    for node in [*tree.body, *nodes]:
        if isinstance(node, ast.Import):
            for a in node.names:
                names[a.asname or a.name.split(".")[0]] = _import(a.name if a.asname else a.name.split(".")[0])
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            mod = _import(node.module)
            for a in node.names:
                obj = getattr(mod, a.name, None) if mod is not None else None
                names[a.asname or a.name] = obj if obj is not None else _import(f"{node.module}.{a.name}")

    def resolve(expr):
        if isinstance(expr, ast.Name):
            return names.get(expr.id)
        if isinstance(expr, ast.Attribute):
            base = resolve(expr.value)
            return getattr(base, expr.attr, None) if inspect.ismodule(base) else None
        return None

    return {id(obj) for n in nodes if (obj := resolve(n)) is not None}


# --------------------------------------------------------------------------- the rule


def test_every_public_function_and_class_has_an_example():
    api = public_api()
    missing = sorted(n for n, obj in api.items()
                     if not has_doctest(obj) and n not in REGISTRY and n not in EXAMPLES and n not in PENDING)
    assert not missing, ("public names with neither a doctest nor an example test (add a '>>>' example to the "
                         "docstring, or an example test registered in tests/test_examples.py): "
                         + ", ".join(missing))


def test_pending_list_only_shrinks():
    api = public_api()
    done = sorted(n for n in PENDING if n not in api or has_doctest(api[n]) or n in REGISTRY or n in EXAMPLES)
    assert not done, f"remove from PENDING (gone, or has an example now): {', '.join(done)}"


def test_registered_examples_exist_and_use_the_name():
    api = public_api()
    problems = []
    for name, where in {**REGISTRY, **EXAMPLES}.items():
        if name not in api:
            problems.append(f"{name}: not a public name (any more)")
            continue
        if has_doctest(api[name]) and name in REGISTRY:
            problems.append(f"{name}: has a doctest; drop its REGISTRY entry")
        file, test = where.split("::")
        used = objects_used(TESTS / file, test)
        if used is None:
            problems.append(f"{name}: no test {where}")
        elif id(api[name]) not in used:
            problems.append(f"{name}: {where} does not use it")
    assert not problems, "; ".join(problems)


@pytest.mark.parametrize("module", sorted(m.__name__ for m in public_modules()
                                          if m.__name__.startswith("lpvpc.validation.")))
def test_validation_doctests(module):
    """lpvpc.validation's doctests (its sources live in validation/, outside pytest's lpvpc/
    doctest collection), run under the installed name."""
    result = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS, verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {module} failed (output above)"


# --------------------------------------------------------------------------- example tests


@example_of("lpvpc.export.exporter.StateLayout", "lpvpc.export.exporter.fmu_variables", "lpvpc.export.exporter.fmu_constants",
            "lpvpc.export.exporter.fmu_description", "lpvpc.export.exporter.system_functions", "lpvpc.export.exporter.write_system_c",
            "lpvpc.export.exporter.generate_c")
def test_example_an_fmu_from_the_export_building_blocks(model, subject, tmp_path):
    """What ``export_fmu`` does, step by step, as a user who wants their own model
    identifier and author would do it: the CasADi system functions, their C code, the FMU
    variables and timing constants, compiled by build_fmu; the FMU replays model.predict."""
    import numpy as np
    from fmpy import extract
    from fmu_helpers import FMUInstance, reference, shifted_error

    from lpvpc.export import exporter as ex
    from lpvpc.export.fmu_build import build_fmu

    layout = ex.state_layout(model, "causal")
    assert isinstance(layout, ex.StateLayout) and layout.latency == 0 and layout.m == model.state_order
    init, output, update, deps = ex.system_functions(model, "causal")
    assert deps["torque_intrinsic"] == ["position", "scheduling", "velocity", "acceleration"]
    sources = ex.write_system_c((init, output, update), tmp_path / "c")
    assert [p.read_text() for p in ex.generate_c(model, tmp_path / "c2", "causal")] == [p.read_text() for p in sources]
    outputs, inputs, parameters = ex.fmu_variables(model, "causal")
    assert [v.name for v in inputs] == ["position", "scheduling", "velocity", "acceleration"]
    constants = ex.fmu_constants(model, "causal")
    assert {c.name: c.start for c in constants} == {"latency": 0.0, "sample_period": 1.0 / model.fs,
                                                     "derivative_points": float(ex.derivative_points(model))}
    path = build_fmu(tmp_path / "my_ankle.fmu", model_identifier="my_ankle", author="a lab",
                     system_sources=[ex.model_source_dir() / "model_system.c", *sources], nx=layout.size,
                     step_size=1.0 / model.fs, outputs=outputs, inputs=inputs, parameters=parameters,
                     description=ex.fmu_description(model, "causal"), constants=constants)

    data = subject["ident"].segment(0, 500)
    inst = FMUInstance(path, extract(path, unzipdir=tmp_path / "x"), "ankle", "cs").initialize()
    rows = ex.replay_inputs(model, data.position, data.scheduling, "causal")
    names = list(rows)
    y = np.empty(data.n)
    for k in range(data.n):
        inst.set(inst.refs(names), [float(rows[n].ravel()[k]) for n in names])
        y[k] = inst.get(inst.refs(["torque"]))[0]
        inst.fmu.doStep(k / model.fs, 1.0 / model.fs)
    inst.fmu.terminate()
    inst.fmu.freeInstance()
    ref = reference(model, data.position, data.scheduling, "causal")["torque"]
    assert shifted_error(y, ref, 0, np.max(np.abs(ref))) < 1e-9


@example_of("lpvpc.validation.cosim.to_rate", "lpvpc.validation.cosim.band_limit",
            "lpvpc.validation.cosim.feedforward_command", "lpvpc.validation.cosim.calibrate_servo",
            "lpvpc.validation.cosim.hold_tail", "lpvpc.validation.cosim.model_variant_inputs")
def test_example_cosimulation_signal_helpers():
    """The master's signal steps on a PRALDS perturbation: to the actuator rate and back,
    band-limited to what a 100 Hz model represents, the servo command that reproduces a
    position, and the servo's bandwidth fitted back from a record."""
    import numpy as np

    from lpvpc.simulation.simulate import pralds
    from lpvpc.validation import cosim

    fs, fs_act = 100.0, 1000.0  # Hz: model rate, actuator rate
    pos = pralds(5.0, fs, np.random.default_rng(0))  # rad
    smooth = cosim.band_limit(cosim.to_rate(pos, fs, fs_act), fs_act, fs)
    back = cosim.to_rate(smooth, fs_act, fs)
    assert len(back) == len(pos) and np.max(np.abs(back - pos)[50:-50]) < 0.15 * np.max(np.abs(pos))
    spectrum = np.abs(np.fft.rfft(smooth * np.hanning(len(smooth))))
    f = np.fft.rfftfreq(len(smooth), 1.0 / fs_act)
    assert spectrum[f > 60].max() < 1e-3 * spectrum.max()  # nothing above the 50 Hz model band

    h, bandwidth, damping = 1.0 / fs_act, 30.0, 0.7  # s, Hz, 1
    command = cosim.feedforward_command(smooth, h, bandwidth, damping)
    with_ff = np.abs(cosim.servo_response(command, h, bandwidth, damping) - smooth)[100:-100]
    without = np.abs(cosim.servo_response(smooth, h, bandwidth, damping) - smooth)[100:-100]
    assert np.sqrt(np.mean(with_ff**2)) < 0.2 * np.sqrt(np.mean(without**2))  # the servo's lag removed
    fit = cosim.calibrate_servo(smooth, cosim.to_rate(cosim.servo_response(smooth, h, 40.0, 0.6), fs_act, fs),
                                h, fs)
    assert abs(fit["servo_bandwidth"] - 40.0) < 0.5 and abs(fit["servo_damping"] - 0.6) < 0.02, fit

    assert cosim.hold_tail(np.array([1.0, 2.0]), 2).tolist() == [1.0, 2.0, 2.0, 2.0]
    assert cosim.model_variant_inputs("causal") == ("position", "scheduling", "velocity", "acceleration")


@example_of("lpvpc.validation.fmu.FMUInfo", "lpvpc.validation.fmu.file_sha256", "lpvpc.validation.fmu.fmu_model_hash",
            "lpvpc.validation.cosim.model_fmu_variant", "lpvpc.validation.cosim.model_fmu_sampled",
            "lpvpc.validation.routes.offline_routes", "lpvpc.validation.routes.casadi_routes",
            "lpvpc.validation.routes.fmu_replay", "lpvpc.validation.routes.model_fmu_inputs",
            "lpvpc.validation.harness.load_record", "lpvpc.validation.harness.Record")
def test_example_prediction_routes_of_an_exported_model(model, subject, tmp_path):
    """What ``lpvpc validate`` checks first, by hand: the exported FMU is the model's (its
    declared hash), and the numpy, CasADi and FMU routes predict the same torque of a
    held-out record loaded from its files."""
    import numpy as np

    from lpvpc.io import write_trial_csv
    from lpvpc.validation import cosim, routes
    from lpvpc.validation.compare import relative_difference
    from lpvpc.validation.fmu import FMUInfo, file_sha256, fmu_model_hash, inspect_fmu
    from lpvpc.validation.harness import Record, load_record

    path = model.export_fmu(tmp_path / "model.fmu")  # the default: sampled, FMI 2
    info = inspect_fmu(path, "model FMU")
    assert isinstance(info, FMUInfo) and info.sha256 == file_sha256(path)
    assert fmu_model_hash(info) == model.model_hash
    assert cosim.model_fmu_variant(info) == "sampled" and cosim.model_fmu_sampled(info)
    assert routes.model_fmu_inputs(model, "sampled") == ("position", "scheduling")

    pair = subject["novel_pair"]
    for trial, name in ((pair.pt, "PT.csv"), (pair.ut, "UT.csv")):
        write_trial_csv(trial, tmp_path / name)
    record = load_record(model, tmp_path / "PT.csv", tmp_path / "UT.csv")
    assert isinstance(record, Record) and record.measured.fs == model.fs
    data = record.measured.segment(0, 1000)
    offline = routes.offline_routes(model, data.position, data.scheduling)
    casadi = routes.casadi_routes(model, data.position, data.scheduling)
    fmu = routes.fmu_replay(info, model, data.position, data.scheduling)
    assert relative_difference(casadi["torque"]["casadi_exact"], offline["numpy"].total) < 1e-9
    assert relative_difference(fmu["torque"], offline["numpy_causal"].total) < 1e-9
    assert np.all(np.isfinite(fmu["torque_reflex"]))


@example_of("lpvpc.validation.harness.ValidationResult", "lpvpc.validation.report.write_metrics")
def test_example_validation_metrics_file(tmp_path):
    """A validation result's metrics as the JSON a lab's scripts read (NaN becomes null)."""
    import json
    import math

    from lpvpc.validation.harness import ValidationResult
    from lpvpc.validation.report import write_metrics

    result = ValidationResult(metrics={"pass": True, "vaf": 97.5, "vaf_fmu": math.nan}, report_dir=tmp_path)
    path = write_metrics(result)
    assert result.passed and result.files["metrics"] == path
    assert json.loads(path.read_text()) == {"pass": True, "vaf": 97.5, "vaf_fmu": None}


@example_of("lpvpc.cli.build_parser", "lpvpc.cli.simulate.run", "lpvpc.cli.identify.run", "lpvpc.cli.predict.run",
            "lpvpc.cli.export.run", "lpvpc.cli.whole_joint.run")
def test_example_command_handlers(tmp_path, capsys):
    """The command line's handlers as ``lpvpc`` calls them (parse, then the command's
    function): a 30-s virtual subject simulated, identified, predicted, exported and turned
    into a whole-joint model; a report folder holding someone else's files is refused."""
    import json

    from lpvpc import cli
    from lpvpc.models.model import LPVPCModel

    def run(handler, *argv):
        assert handler(cli.build_parser().parse_args([str(a) for a in argv])) == 0
        return capsys.readouterr().out

    data, model = tmp_path / "data", tmp_path / "model.json"
    run(cli.simulate.run, "simulate", "--out", data, "--seed", 0, "--duration", 30)
    run(cli.identify.run, "identify", "--pt", data / "ident_PT.csv", "--ut", data / "ident_UT.csv", "-o", model)
    out = run(cli.predict.run, "predict", model, "--pt", data / "ident_PT.csv", "--ut", data / "ident_UT.csv",
              "--json", tmp_path / "m.json")
    vaf = json.loads((tmp_path / "m.json").read_text())["vaf"]
    assert f"{vaf:.2f}" in out and vaf == pytest.approx(LPVPCModel.load(model).fit["vaf"], abs=0.01)
    run(cli.export.run, "export", model, "--casadi", tmp_path / "model.casadi")
    assert (tmp_path / "model.casadi").is_file()
    run(cli.whole_joint.run, "whole-joint", model, "--ut", data / "ident_UT.csv", "-o", tmp_path / "whole.json")
    assert json.loads((tmp_path / "whole.json").read_text())["model"]["fs"] == 100.0

    cli._common.check_report_folder(tmp_path / "new_report", ["report.html"], force=False)  # absent: fine
    with pytest.raises(Exception, match="holds files but no previous report"):
        cli._common.check_report_folder(data, ["report.html"], force=False)


@example_of("lpvpc.models.effects.Effect", "lpvpc.models.effects.FittedEffect", "lpvpc.models.effects.Context", "lpvpc.models.effects.Setting",
            "lpvpc.models.effects.model_signals", "lpvpc.models.effects.model_derived", "lpvpc.models.effects.predict_effects",
            "lpvpc.models.effects.default_signals", "lpvpc.models.effects.record_context", "lpvpc.models.effects.effect_term",
            "lpvpc.models.effects.quiet_mask", "lpvpc.models.effects.check_signals", "lpvpc.models.effects.channel_basis",
            "lpvpc.models.effects.effect_basis", "lpvpc.models.effects.effect_options")
def test_example_an_extended_model_and_its_effect_terms():
    """A subject whose torque drifts over the trial, identified with the catalog's "drift"
    effect: the model asks for the trial time as an extra signal, and the drift term, taken
    apart by hand from the record's context, is what predict_effects and predict report."""
    import numpy as np

    from lpvpc.models import effects as fx
    from lpvpc.models import equations as eq
    from lpvpc.io import pair_trials
    from lpvpc.errors import DataError
    from lpvpc.identification.identify import identify
    from lpvpc.simulation.simulate import simulate_pair

    pair = simulate_pair("multilevel", seed=4, effects=("drift",), duration=30.0, fs_out=100.0)
    data = pair_trials(pair.pt, pair.ut)
    model = identify(data, effects=("drift",))
    (fe,) = model.effects
    assert isinstance(fe, fx.FittedEffect) and isinstance(fe.effect, fx.Effect) and fe.effect is fx.CATALOG["drift"]
    assert fx.model_signals(model) == model.signals == ("trial_time",) and fx.model_derived(model) == set()
    assert isinstance(fx.SETTINGS["reflex_delay"], fx.Setting)

    signals = fx.default_signals(data.scheduling, data.fs)  # trial_time = k / fs (s)
    assert np.allclose(signals["trial_time"][:3], [0.0, 0.01, 0.02])
    fx.check_signals(signals, model.signals, data.n)
    with pytest.raises(DataError, match="trial_time"):
        fx.check_signals({}, model.signals, data.n)
    assert fx.effect_options(fe.effect, signals) == {}
    assert fx.channel_basis(fe.effect, model.intrinsic_basis).order < model.intrinsic_basis.order
    assert fx.effect_basis(fe.effect, model.intrinsic_basis) is None  # no static features

    ctx = fx.record_context(data.position, data.scheduling, data.fs, signals)
    assert isinstance(ctx, fx.Context) and ctx.rho.shape == (data.n, 1)
    term = fx.effect_term(fe, ctx, eq.lagged(data.position, model.lags), model.intrinsic_basis.evaluate(data.scheduling),
                          "exact")
    pathway, torque = fx.predict_effects(model, data.position, data.scheduling, signals)["drift"]
    assert pathway == "intrinsic" and np.allclose(np.ravel(term), torque)
    assert np.allclose(model.predict(data, warn=False).effects["drift"], torque)

    quiet = fx.quiet_mask(data.position, data.fs)  # no perturbation movement lately
    assert quiet.dtype == bool and 0.2 < quiet.mean() < 0.8
    assert np.all(np.abs(eq.velocity(data.position, data.fs)[quiet]) < 0.1 * np.abs(eq.velocity(data.position,
                                                                                                 data.fs)).max())


@example_of("lpvpc.diagnosis.diagnose.Diagnosis", "lpvpc.diagnosis.diagnose.record_coverage", "lpvpc.diagnosis.diagnose.check_record",
            "lpvpc.diagnosis.candidates.CandidateResult", "lpvpc.diagnosis.candidates.score_candidates",
            "lpvpc.diagnosis.candidates.reflex_leak", "lpvpc.diagnosis.signals.candidate_signals",
            "lpvpc.diagnosis.signals.signal_dependence", "lpvpc.diagnosis.where.where_it_fails",
            "lpvpc.diagnosis.report.format_table", "lpvpc.diagnosis.report.candidates_html",
            "lpvpc.diagnosis.report.diagnosis_html", "lpvpc.plotting.plot_residual_diagnosis")
def test_example_diagnosing_a_missing_effect():
    """A subject whose stiffness depends on the direction of the slow movement, modelled
    without that effect: the diagnosis of a held-out record names it, and each piece of the
    diagnosis (the surrogate's candidate scores, the residual's dependence on signals, where
    the model fails, the tables and the figure) can be had on its own."""
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.figure import Figure

    from lpvpc import diagnose as D
    from lpvpc.io import pair_trials
    from lpvpc.errors import InsufficientExcitationError
    from lpvpc.identification.identify import identify
    from lpvpc.plotting import plot_residual_diagnosis
    from lpvpc.simulation.simulate import simulate_pair

    effect = "direction_dependent_stiffness"
    ident = simulate_pair("multilevel", seed=4, effects=(effect,), duration=60.0, fs_out=100.0)
    held = simulate_pair("multilevel", seed=5, effects=(effect,), duration=60.0, fs_out=100.0)
    # structure fixed: the diagnosis is the subject here (a structure selected on these data can
    # take up part of the missing stiffness, and the residual's dependence then ranks trial time first)
    model, data = identify(pair_trials(ident.pt, ident.ut), structure="fixed"), pair_trials(held.pt, held.ut)

    coverage = D.record_coverage(model, data)  # s, fractions of the identified range
    assert coverage["duration_s"] == 60.0 and coverage["outside_fraction"] == 0.0
    assert D.check_record(model, data)["duration_s"] == 60.0
    with pytest.raises(InsufficientExcitationError):
        D.check_record(model, data.segment(0, 200))  # 2 s: too short to say anything
    diag = D.diagnose(model, data, dependence=False)
    assert isinstance(diag, D.Diagnosis) and isinstance(diag.top, D.CandidateResult)
    assert diag.top.effect == effect and diag.top.vaf_gain > 0.3  # percentage points
    assert effect in D.format_table(diag) and effect in D.candidates_html(diag)
    assert "<table" in D.diagnosis_html(diag)

    sur = D.Surrogate(model, data)
    results, _ = D.score_candidates(sur, candidates=[effect, "drift"])
    assert [r.effect for r in results][0] == effect
    signals = D.candidate_signals(sur)
    assert "emg" in signals and 0.0 <= D.reflex_leak(sur, signals["emg"][0]) <= 1.0
    dependence = D.signal_dependence(sur, top=3)  # the residual depends on position (the missing stiffness)
    assert dependence[0]["signal"] == "position" and dependence[0]["vaf_gain"] >= dependence[-1]["vaf_gain"]
    where = D.where_it_fails(model, data, diag.residual)
    assert {"position", "velocity", "frequency", "whiteness"} <= set(where)
    fig = plot_residual_diagnosis(diag, data)
    assert isinstance(fig, Figure)
    plt.close(fig)


@example_of("lpvpc.models.effects.EffectDesign", "lpvpc.models.effects.effect_columns", "lpvpc.models.effects.causal_irf",
            "lpvpc.models.effects.finish_extended_fit")
def test_example_an_extended_fit_by_hand():
    """What ``identify(data, effects=("drift",))`` does with the effect's columns, by hand on
    a subject whose torque drifts: the design holds the drift's regressor columns (the
    record's position lags scheduled by the trial time), they join the intrinsic regressor
    in one least-squares solve with the base model's reflex held, and finish_extended_fit
    turns the coefficients into the model's drift term, whose causal IRF is fitted to its
    two-sided torque as the base model's is."""
    import copy

    import numpy as np

    from lpvpc.models import effects as fx
    from lpvpc.models import equations as eq
    from lpvpc.io import pair_trials
    from lpvpc.identification.identify import identify
    from lpvpc.models.intrinsic import curvature_from_irf, curvature_regressor, intrinsic_regressor
    from lpvpc.models.model import vaf
    from lpvpc.simulation.simulate import simulate_pair

    pair = simulate_pair("multilevel", seed=4, effects=("drift",), duration=30.0, fs_out=100.0)
    data = pair_trials(pair.pt, pair.ut)
    p, rho, fs = data.position, data.scheduling, data.fs  # rad, rad, Hz
    base = identify(data, structure="fixed")  # the extended fit below is not selected either: the same structure
    Gi = base.intrinsic_basis.evaluate(rho)

    # the base model's causal IRF is the least-squares causal fit of its two-sided torque
    two_sided = eq.intrinsic_torque(eq.lagged(p, base.lags), Gi, base.H)  # N m
    H_causal = fx.causal_irf(p, fs, base.causal_lags, Gi, two_sided, base.causal_derivatives)
    assert np.allclose(H_causal, base.H_causal, rtol=1e-6, atol=1e-9 * np.abs(base.H_causal).max())

    design = fx.EffectDesign(("drift",), p, rho, fs, base.lags, base.intrinsic_basis, fx.signals_from_data(data))
    (name, kind, width), = design.blocks
    assert (name, kind) == ("drift", "irf") and design.columns.shape == (data.n, width)
    assert design.reflex_columns(base)[1] == []  # no reflex-pathway effect
    ctx = fx.record_context(p, rho, fs, design.signals)
    irf, static = fx.effect_columns(fx.CATALOG["drift"], design.options["drift"], ctx, p, base.lags,
                                    design.channel_values["drift"], design.bases["drift"])
    assert static is None and np.array_equal(irf, design.columns)

    Psi_irf = intrinsic_regressor(p, Gi, base.lags)
    # the elastic curvature, tied to the IRF's stiffness, adds its share to every lag's columns
    Psi = Psi_irf + np.tile(curvature_regressor(p, Gi, base.intrinsic_basis), len(base.lags))
    y = data.torque - base.predict(data, warn=False).reflex  # N m: the intrinsic share, the reflex held
    theta = np.linalg.lstsq(np.hstack([Psi, design.columns]), y, rcond=None)[0]
    model = copy.deepcopy(base)
    model.H = theta[:Psi.shape[1]].reshape(base.H.shape)
    model.curvature = curvature_from_irf(model.H, base.intrinsic_basis)  # N m/rad^2
    model.H_causal = fx.causal_irf(p, fs, model.causal_lags, Gi, Psi_irf @ theta[:Psi.shape[1]], model.causal_derivatives)
    fx.finish_extended_fit(design, model, theta[Psi.shape[1]:], Psi, data.torque, Psi_irf=Psi_irf)
    (fe,) = model.effects
    assert fe.name == "drift" and fe.H.size == width and model.signals == ("trial_time",)
    pred = model.predict(data, warn=False)
    assert np.allclose(pred.effects["drift"], design.columns @ theta[Psi.shape[1]:])
    v_base, v_drift = vaf(data.torque, base.predict(data, warn=False).total), vaf(data.torque, pred.total)  # %
    v_identify = identify(data, effects=("drift",)).fit["vaf"]
    # the drift costs the base model about 0.15 points on 30 s; the hand fit recovers what identify's does
    assert v_drift > v_base + 0.08 and abs(v_drift - v_identify) < 0.08, (v_base, v_drift, v_identify)


def test_example_sigterm_takes_the_ctrl_c_path(subject, tmp_path, capsys):
    """SIGTERM while ``lpvpc identify`` runs: main turns it into Terminated, a KeyboardInterrupt,
    so the command stops as after Ctrl-C: exit status 128 + 15, one line on stderr, no model
    file and no temporary file left."""
    import os
    import signal
    import threading
    import time

    from lpvpc import cli

    assert issubclass(cli.Terminated, KeyboardInterrupt)
    late = []

    def guard(signum, frame):  # a SIGTERM outside main's handler would end pytest
        late.append(signum)

    done = threading.Event()

    def terminate_once_main_listens():
        while signal.getsignal(signal.SIGTERM) is guard and not done.is_set():
            time.sleep(0.001)
        if not done.is_set():
            time.sleep(0.05)  # s: inside identify (loading and decimating 2 min at 1 kHz)
            os.kill(os.getpid(), signal.SIGTERM)

    previous = signal.signal(signal.SIGTERM, guard)
    sender = threading.Thread(target=terminate_once_main_listens)
    try:
        sender.start()
        status = cli.main(["identify", "--pt", str(subject["folder"] / "ident_PT.csv"),
                           "--ut", str(subject["folder"] / "ident_UT.csv"), "-o", str(tmp_path / "model.json")])
    finally:
        done.set()
        sender.join()
        signal.signal(signal.SIGTERM, previous)
    err = capsys.readouterr().err
    assert not late and status == 128 + signal.SIGTERM, (late, status, err)
    assert err.strip().splitlines() == ["lpvpc: error: terminated"]
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def held_out_cut(model, subject, tmp_path_factory):
    """The first 10 s of the session's novel record (1 kHz trials with their command
    channels) paired at the model's rate, the model's exact FMU and the actuator FMU (FMI 2.0)."""
    from lpvpc.export.actuator import build_actuator_fmu
    from lpvpc.io import Trial
    from lpvpc.export.exporter import export_fmu
    from lpvpc.validation.fmu import inspect_fmu
    from lpvpc.validation.harness import load_record

    folder = tmp_path_factory.mktemp("held_out_cut")
    pair, n = subject["novel_pair"], 10_000
    pt, ut = (Trial(t.time[:n], t.position[:n], t.torque[:n], {k: v[:n] for k, v in t.channels.items()}, name=t.name)
              for t in (pair.pt, pair.ut))
    return {"pt": pt, "ut": ut, "record": load_record(model, pt, ut),
            "model_fmu": inspect_fmu(export_fmu(model, folder / "model.fmu", variant="exact"), "model FMU"),
            "actuator_fmu": inspect_fmu(build_actuator_fmu(folder / "actuator.fmu"), "actuator FMU")}


@example_of("lpvpc.validation.cosim.ActuatorDrive", "lpvpc.validation.cosim.CosimResult",
            "lpvpc.validation.ssp.portable_ssp_from_run", "lpvpc.validation.engines.ssp_steps")
def test_example_a_cosimulation_by_hand_and_its_portable_ssp(model, held_out_cut, tmp_path):
    """The lab experiment without ``validate``: the actuator's servo fitted to the record,
    the record's 1 kHz commands (band-limited to the model's band) drive two actuator FMUs,
    the model's exact FMU plays the ankle on their position difference and loads the PT
    actuator (its latency L removed); the same run as an SSP archive that a co-simulation
    engine runs as it is."""
    import numpy as np

    from lpvpc.export.exporter import latency_samples
    from lpvpc.models.model import vaf
    from lpvpc.validation.cosim import (ActuatorDrive, CosimResult, CosimSettings, band_limit, calibrate_servo,
                                        run_cosimulation)
    from lpvpc.validation.engines import available, run_portable_ssp, ssp_steps
    from lpvpc.validation.ssp import instance_parameters, portable_ssp_from_run

    cut = held_out_cut
    pt, ut, meas = cut["pt"], cut["ut"], cut["record"].measured
    h, ratio, K = 1e-3, 10, meas.n  # s (actuator step), actuator steps per model step, model steps
    command_ut, command_pt = ut.channels["command"], pt.channels["command"]  # rad, at 1 kHz like the actuator
    servo = calibrate_servo(command_pt - command_ut, pt.position - ut.position, h, 1000.0)
    servo = {k: servo[k] for k in ("servo_bandwidth", "servo_damping")}  # Hz, 1
    drive = ActuatorDrive(command_ut=band_limit(command_ut, 1 / h, model.fs),
                          command_pt=band_limit(command_pt, 1 / h, model.fs), load_ut=ut.torque, step=h, ratio=ratio,
                          n_model=K, source="the record's command channels, band-limited")
    L = latency_samples(model, "exact")  # model steps
    cos = run_cosimulation(cut["model_fmu"], cut["actuator_fmu"], drive, actuator_parameters=servo, latency=L)
    assert isinstance(cos, CosimResult) and (cos.variant, cos.latency) == ("exact", L)
    assert len(cos.time) == len(cos.torque) == K and cos.ut.shape == cos.pt.shape == (K * ratio, 3)
    assert (cos.step_model, cos.step_actuator) == (0.01, h) and cos.parameters == servo
    ok = np.isfinite(cos.torque)
    offline = vaf(meas.torque, model.predict(meas.position, meas.scheduling, warn=False).total)  # %
    assert vaf(meas.position, cos.model_inputs["position"]) > 99.9  # the actuators reproduce the perturbation
    assert vaf(meas.torque[ok], cos.torque[ok]) > offline - 0.5, (vaf(meas.torque[ok], cos.torque[ok]), offline)

    params = instance_parameters(cos.parameters, drive.command_ut[0], drive.command_pt[0])
    ssp = portable_ssp_from_run(tmp_path / "lab.ssp", cut["model_fmu"], cut["actuator_fmu"], drive, params,
                                cos.settings, L, tmp_path / "record.fmu")
    assert ssp == tmp_path / "lab.ssp" and (tmp_path / "record.fmu").is_file()
    base_step, model_step, stop = ssp_steps(ssp)  # s
    assert (base_step, model_step) == (h, 0.01) and stop == pytest.approx((K + L) * 0.01)
    # a set-up that needs the master's arithmetic has no connections-only form
    assert portable_ssp_from_run(tmp_path / "x.ssp", cut["model_fmu"], cut["actuator_fmu"], drive, params,
                                 CosimSettings(load="model"), L, tmp_path / "x.fmu") is None
    why = available("libcosim")
    if why:
        pytest.skip(why)
    y = run_portable_ssp(ssp, "libcosim")[L:L + K]
    assert abs(vaf(meas.torque[ok], y[ok]) - vaf(meas.torque[ok], cos.torque[ok])) < 1.0


@example_of("lpvpc.validation.ssp.build_record_fmu", "lpvpc.validation.ssp.write_portable_ssp")
def test_example_the_record_player_fmu_and_a_portable_ssp(held_out_cut, tmp_path):
    """The record player plays one recorded sample per step and computes the harness's
    signals from the inputs it took at the start of the last step (no output depends on the
    current inputs); with the model and actuator FMUs it makes a portable SSP whose
    connections all join two elements."""
    import xml.etree.ElementTree as ET
    import zipfile

    from lpvpc.errors import FMUError
    from lpvpc.validation.fmu import FMUInstance, inspect_fmu
    from lpvpc.validation.ssp import (PORTABLE_CONNECTIONS, RECORD_INPUTS, RECORD_OUTPUTS, SSD_NAMESPACES,
                                      build_record_fmu, write_portable_ssp)

    h = 1e-3  # s
    command_ut, command_pt, torque_ut = [0.0, 0.01, 0.02], [0.0, -0.01, 0.03], [1.0, 2.0, 3.0]  # rad, rad, N m
    record = inspect_fmu(build_record_fmu(tmp_path / "record.fmu", command_ut, command_pt, torque_ut, h), "record FMU")
    with FMUInstance(record, "record") as inst:
        inst.initialize(0.0)
        inputs, outputs = inst.port(RECORD_INPUTS, "input"), inst.port(RECORD_OUTPUTS, "output")
        prev = None
        for k in range(4):  # the last sample is held after the end
            j = min(k, 2)
            u = dict(pt_position=0.1 * k, ut_position=0.02, model_torque=5.0 + k, pt_velocity=2.0, ut_velocity=-1.0,
                     pt_acceleration=40.0, ut_acceleration=0.0)  # rad, N m, rad/s, rad/s2
            inputs.set([u[n] for n in RECORD_INPUTS])
            y = dict(zip(RECORD_OUTPUTS, outputs.get()))
            assert (y["command_ut"], y["command_pt"], y["load_ut"]) == (command_ut[j], command_pt[j], torque_ut[j])
            if prev is None:  # before the first step: the actuators at rest at their first commands
                assert (y["load_pt"], y["perturbation"]) == (torque_ut[0], command_pt[0] - command_ut[0])
            else:  # from the inputs of the last step, one step ahead
                assert y["load_pt"] == pytest.approx(torque_ut[j] + prev["model_torque"])
                assert y["perturbation"] == pytest.approx(0.1 * (k - 1) - 0.02 + h * 3.0 + h**2 / 2 * 40.0)
            inst.do_step(k * h, h)
            prev = u

    ssp = write_portable_ssp(tmp_path / "lab.ssp", held_out_cut["model_fmu"], held_out_cut["actuator_fmu"], record,
                             stop_time=3 * h, parameters={"actuator_pt": {"servo_bandwidth": 30.0}})  # Hz
    with zipfile.ZipFile(ssp) as zf:
        assert sorted(zf.namelist()) == ["SystemStructure.ssd", "resources/actuator.fmu", "resources/model.fmu",
                                         "resources/record.fmu"]
        root = ET.fromstring(zf.read("SystemStructure.ssd"))
    links = {((c.get("endElement"), c.get("endConnector")), (c.get("startElement"), c.get("startConnector")))
             for c in root.iter(f"{{{SSD_NAMESPACES['ssd']}}}Connection")}
    assert links == set(PORTABLE_CONNECTIONS)
    with pytest.raises(FMUError, match="actuator_ut: no parameter named 'stiffness'"):
        write_portable_ssp(tmp_path / "bad.ssp", held_out_cut["model_fmu"], held_out_cut["actuator_fmu"], record,
                           stop_time=3 * h, parameters={"actuator_ut": {"stiffness": 1.0}})


@example_of("lpvpc.validation.report.write_report")
def test_example_a_validation_report_drawn_from_the_runs_parts(model, held_out_cut, tmp_path):
    """``validate(..., write_report=False)`` measures only; the report is drawn afterwards from
    the run's parts, recomputed with the harness's own steps (the same calibrated servo and
    band-limited commands, hence the same co-simulation): offline routes, the FMU replaying
    the measured positions, the co-simulation."""
    import numpy as np

    from lpvpc.export.exporter import latency_samples
    from lpvpc.models.model import vaf
    from lpvpc.validation import routes, validate
    from lpvpc.validation.cosim import run_cosimulation
    from lpvpc.validation.harness import actuator_drive, check_actuator_fmu
    from lpvpc.validation.report import FIGURES, write_report

    cut = held_out_cut
    mf, af, record = cut["model_fmu"], cut["actuator_fmu"], cut["record"]
    result = validate(model, cut["pt"], cut["ut"], tmp_path / "report", fmu=mf.path, actuator_fmu=af.path,
                      write_report=False, measure_load_effect=False)
    m, meas = result.metrics, record.measured
    assert not (tmp_path / "report" / "report.html").exists()

    off = routes.offline_routes(model, meas.position, meas.scheduling, data=meas)
    replay = routes.fmu_replay(mf, model, meas.position, meas.scheduling)
    drive, params, _ = actuator_drive(record, af, check_actuator_fmu(af, model, {}), meas.n, {}, calibrate=True,
                                      band_limit_to=model.fs)
    cos = run_cosimulation(mf, af, drive, actuator_parameters=params, latency=latency_samples(model, "exact"))
    ok = np.isfinite(cos.torque)
    assert vaf(meas.torque[ok], cos.torque[ok]) == pytest.approx(m["vaf_cosim"], abs=1e-9)  # the run measured
    assert vaf(meas.torque, off["identified"].total) == pytest.approx(m["vaf"], abs=1e-9)

    files = write_report(result, model=model, record=record, predictions={
        "numpy": off["identified"], "numpy_model_rate": off["numpy"], "numpy_causal": off["numpy_causal"],
        "fmu": replay, "cosim": cos})
    assert files["report"] == tmp_path / "report" / "report.html"
    assert set(files["figures"]) == set(FIGURES) and result.metrics["files"]["report"] == "report.html"
    for png in files["figures"].values():
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"{m['vaf_cosim']:.2f} %" in files["report"].read_text()


@example_of("lpvpc.validation.whole_joint.evaluate_whole_joint")
def test_example_the_whole_joint_model_on_a_held_out_record(model, subject, held_out_cut, tmp_path):
    """The whole-joint model (angle in, total torque out) fitted to the identification UT
    trial, measured on the held-out PT trial: numpy, CasADi and its FMU agree, and its own
    perturbation part comes close to the two-input model fed the measured split."""
    from pathlib import Path

    import numpy as np

    from lpvpc.models.model import vaf
    from lpvpc.validation.whole_joint import evaluate_whole_joint
    from lpvpc.export.whole_joint import fit_whole_joint

    wj = fit_whole_joint(model, subject["ident_pair"].ut)
    meas = held_out_cut["record"].measured
    metrics, traces = evaluate_whole_joint(wj, held_out_cut["record"], tmp_path)  # the FMU goes to tmp_path
    assert Path(metrics["fmu"]) == tmp_path / "whole_joint_fmi2.fmu" and metrics["fmi_version"] == 2
    assert metrics["vaf_total"] > 98 and abs(metrics["vaf_total_fmu"] - metrics["vaf_total"]) < 0.05  # %
    assert metrics["fmu_vs_numpy"] < 1e-9 and metrics["casadi_vs_numpy"] < 1e-9
    assert metrics["vaf_perturbation"] > metrics["vaf_two_input"] - 2  # issue 12's floor
    assert metrics["latency_s"] == metrics["latency_samples"] / model.fs
    assert all(len(v) == meas.n for v in traces.values())
    assert np.allclose(traces["angle"], meas.position + meas.scheduling)  # the PT trial's joint angle, rad
    assert vaf(traces["measured"], traces["predicted"]) == pytest.approx(metrics["vaf_total"])


@pytest.mark.slow
@example_of("lpvpc.demo.run")
def test_example_the_demo(tmp_path, capsys):
    """``make demo`` (``python -m lpvpc.demo OUTDIR``, about 25 s of CPU: the one example
    that cannot be shorter, as its 2-minute trials are what a new user first sees):
    the held-out VAF near the noise ceiling, K(theta) near the truth, every file written,
    the validation passing, the improve loop finding the hidden effect and the closed-loop
    FMU following the subject in the compliant loop where the replay FMU diverges."""
    import json
    import re

    from lpvpc import demo
    from lpvpc.models.model import LPVPCModel

    out = tmp_path / "demo_out"
    assert demo.run(out) == 0
    text = capsys.readouterr().out

    def number(pattern):
        return float(re.search(pattern, text).group(1))

    assert number(r"gap to the ceiling:\s+(-?[\d.]+) percentage points") < 1.5
    assert number(r"worst \|error\| ([\d.]+) %") < 10.0  # K(theta), central 80 % of the range
    assert "+ direction_dependent_stiffness" in text and "stopped: nothing significant left" in text
    before, after = map(float, re.search(r"held-out error: VAF ([\d.]+) % -> ([\d.]+) %", text).groups())
    assert after > before + 0.5
    assert LPVPCModel.load(out / "model.json").fs == 100.0
    for name in ("model.casadi", "model.fmu", "validation/report.html", "improve/report.html",
                 *(f"figures/{f}" for f in ("fig3_torque.png", "fig4_intrinsic_gain.png",
                                            "fig5a_reflex_nonlinearity.png", "fig5b_reflex_irf.png",
                                            "stiffness_vs_truth.png"))):
        assert (out / name).stat().st_size > 0, name
    assert json.loads((out / "validation" / "metrics.json").read_text())["pass"] is True
    # step 9: in the compliant loop the closed-loop FMU follows the subject; the replay FMU does not
    loops = re.findall(r"Kp\s+(\d+) N m/rad: closed-loop FMU angle deviation VAF ([\d.]+) %, torque ([\d.]+) %.*?"
                       r"replay FMU \(40 ms latency\) (diverges|stable)", text)
    assert [kp for kp, *_ in loops] == ["40", "150"], text
    assert all(float(dev) >= 95 and float(tq) >= 95 and replay == "diverges" for _, dev, tq, replay in loops)
    assert (out / "closed_loop" / "closed_loop.html").stat().st_size > 0
