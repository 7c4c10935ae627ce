"""Export: the fitted model as a CasADi step function and as FMUs (FMI 2 and 3,
co-simulation and Model Exchange), built from the C sources in ``lpvpc/export/c``; the
actuator FMU; whole-joint and closed-loop models for controller design.

The exporter's public names are importable from here (``from lpvpc.export import
export_fmu``); the modules are :mod:`~lpvpc.export.exporter`, :mod:`~lpvpc.export.fmu_build`,
:mod:`~lpvpc.export.actuator`, :mod:`~lpvpc.export.whole_joint` and
:mod:`~lpvpc.export.closed_loop`.
"""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {"exporter": [
    "VARIANTS", "OUTPUT_NAMES", "StateLayout", "step_function", "input_names", "state_layout", "latency_samples",
    "parameter_vector", "parameter_names", "parameter_info", "export_casadi", "trajectory_function",
    "replay_inputs", "export_fmu", "DEFAULT_VARIANT", "DEFAULT_FMU_VARIANT", "save_casadi", "load_casadi",
    "CasadiExport", "ticks_per_sample", "fmu_constants", "derivative_points", "fmu_variables",
    "fmu_parameter_name", "fmu_description", "system_functions", "generate_c", "write_system_c",
    "step_system_functions", "build_step_fmu", "model_source_dir"]})
