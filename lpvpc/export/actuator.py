"""The hydraulic rotary actuator that moves the foot, as a co-simulation FMU.

A stiff position servo (see ``lpvpc/export/c/actuator/README.md`` for the equations)::

    theta_m'' = wn^2 (command - theta_m) - 2 zeta wn theta_m'              (servo loop)
    J theta'' = K_s (theta_m - theta) + B_c (theta_m' - theta') - load_torque   (footplate)
    wn = 2 pi servo_bandwidth,  B_c = 2 coupling_damping sqrt(K_s J)

Inputs: ``command`` (rad), ``load_torque`` (N m, torque of the ankle on the footplate).
Outputs: ``position`` (rad), ``velocity`` (rad/s), ``acceleration`` (rad/s^2; the only output
with direct feedthrough, of ``load_torque``). Parameters (fixed): see :data:`ACTUATOR_DEFAULTS`.
Internal step 1 ms, exact zero-order-hold discretisation; communication steps must be
multiples of 1 ms. The actuator starts at rest at ``initial_position`` with the footplate
undeflected: set ``initial_position`` to the first command.
"""

from __future__ import annotations

import os
from pathlib import Path

from lpvpc.export.fmu_build import FmuVariable, build_fmu, wrapper_dir

__all__ = ["ACTUATOR_DEFAULTS", "ACTUATOR_STEP", "ACTUATOR_MODEL_IDENTIFIER", "actuator_variables",
           "actuator_build_kwargs", "build_actuator_fmu", "actuator_source_dir"]

#: Parameter defaults, in value-reference order (SI units; bandwidth in Hz).
ACTUATOR_DEFAULTS: dict[str, float] = {
    "servo_bandwidth": 40.0,      # Hz, small-signal position bandwidth of the servo loop
    "servo_damping": 0.7,         # 1, damping ratio of the servo loop
    "footplate_inertia": 0.02,    # kg m^2, footplate (and coupling) inertia
    "servo_stiffness": 2.0e4,     # N m/rad, stiffness of motor-to-footplate against load torque
    "coupling_damping": 0.7,      # 1, damping ratio of the footplate mode sqrt(K_s/J)
    "initial_position": 0.0,      # rad, position at rest at t = 0
}

ACTUATOR_STEP = 1e-3  # s, internal fixed step
ACTUATOR_MODEL_IDENTIFIER = "lpvpc_actuator"

_PARAMETER_INFO = {
    "servo_bandwidth": ("Hz", "Natural frequency of the servo loop, wn = 2 pi servo_bandwidth"),
    "servo_damping": ("1", "Damping ratio of the servo loop"),
    "footplate_inertia": ("kg.m2", "Inertia J of the footplate"),
    "servo_stiffness": ("N.m/rad", "Stiffness K_s between motor and footplate: static deflection = "
                                   "load_torque / K_s"),
    "coupling_damping": ("1", "Damping ratio of the footplate mode: B_c = 2 coupling_damping sqrt(K_s J)"),
    "initial_position": ("rad", "Position at t = 0 (at rest, footplate undeflected); set it to the "
                                "first command"),
}


def actuator_source_dir() -> Path:
    """Folder with ``actuator.c`` and its README."""
    return wrapper_dir().parent / "actuator"


def actuator_variables() -> tuple[list[FmuVariable], list[FmuVariable], list[FmuVariable]]:
    """(outputs, inputs, parameters) of the actuator FMU, in value-reference order.

    >>> outputs, inputs, parameters = actuator_variables()
    >>> [(v.name, v.unit) for v in outputs[:3]]
    [('position', 'rad'), ('velocity', 'rad/s'), ('acceleration', 'rad/s2')]
    """
    outputs = [
        FmuVariable("position", "output", "rad", "Footplate angle theta", dependencies=[]),
        FmuVariable("velocity", "output", "rad/s", "Footplate angular velocity", dependencies=[]),
        FmuVariable("acceleration", "output", "rad/s2",
                    "Footplate angular acceleration (depends directly on load_torque)",
                    dependencies=["load_torque"]),
    ]
    inputs = [
        FmuVariable("command", "input", "rad", "Commanded footplate angle", 0.0),
        FmuVariable("load_torque", "input", "N.m",
                    "Torque exerted by the ankle on the footplate (positive pushes the footplate "
                    "toward negative angles)", 0.0),
    ]
    parameters = [FmuVariable(name, "parameter", unit, text, ACTUATOR_DEFAULTS[name])
                  for name, (unit, text) in _PARAMETER_INFO.items()]
    return outputs, inputs, parameters


def _default_path(fmi_version: int) -> Path:
    # A per-user cache, not the package folder: an installed package may be read-only.
    cache = os.environ.get("LPVPC_CACHE") or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "lpvpc"
    return Path(cache) / "fmus" / f"actuator_fmi{fmi_version}.fmu"


def actuator_build_kwargs(fmi_version: int = 2) -> dict:
    """Keyword arguments of :func:`lpvpc.export.fmu_build.build_fmu` for the actuator (without the
    path); also usable with :func:`lpvpc.export.fmu_build.fmu_guid`."""
    outputs, inputs, parameters = actuator_variables()
    return dict(
        model_identifier=ACTUATOR_MODEL_IDENTIFIER,
        system_sources=[actuator_source_dir() / "actuator.c"],
        nx=4,
        step_size=ACTUATOR_STEP,
        outputs=outputs,
        inputs=inputs,
        parameters=parameters,
        fmi_version=fmi_version,
        description=("Hydraulic rotary actuator as a stiff position servo (2nd-order servo loop) "
                     "driving a footplate through a finite stiffness; exact zero-order-hold "
                     "discretisation."),
        version="1.0",
        latency=0.0,
    )


def build_actuator_fmu(path=None, fmi_version: int = 2, *, timings: dict | None = None) -> Path:
    """Build the actuator FMU (FMI 2.0 or 3.0 co-simulation) and return its path.

    ``path`` defaults to ``build/fmus/actuator_fmi<version>.fmu`` in the source tree. The FMU
    is rebuilt only if its sources, settings or the builder changed (the GUID is a hash of
    them). ``timings``: see :func:`lpvpc.export.fmu_build.build_fmu`.
    """
    path = Path(path) if path is not None else _default_path(fmi_version)
    return build_fmu(path, **actuator_build_kwargs(fmi_version), reuse_existing=True, timings=timings)
