"""The co-simulation set-up as an SSP 1.0 archive (System Structure and Parameterization),
so that other tools can load the components, connections and parameters the harness uses.

Units: time s, angles rad, torque N m (the FMUs' own units are copied into the SSD).

The archive (:func:`write_ssp`) is a zip with ``SystemStructure.ssd`` at its root and the
FMUs under ``resources/``: one component per FMU instance of :func:`lpvpc.validation.cosim.run_cosimulation`
(``actuator_ut`` and ``actuator_pt`` share ``resources/actuator.fmu``; ``model`` is
``resources/model.fmu``), each with a connector for every input, output and parameter of
its model description (name, kind and type as declared there).

The connections are those of :func:`lpvpc.validation.cosim.connections` for the given settings:

- a source that is one output of another instance (e.g. ``model.scheduling`` from
  ``actuator_ut.position``) becomes an SSP connection between the two components;
- a source the master computes or takes from the record (commands, the perturbation
  position ``actuator_pt.position - actuator_ut.position``, its central differences, the
  measured UT torque, an extended model's extra signals) becomes an input connector of the
  system, named ``<instance>_<variable>`` and connected to that input: SSP 1.0 connections
  carry one source and no arithmetic, so the tool that runs the system supplies these (the
  formula is in the system's ``org.lpvpc.cosimulation`` annotation);
- a constant ``0`` source is a system input connector too, bound to 0 in the parameter set.

Parameters the harness sets (the actuator parameters, calibrated or given, and each
instance's ``initial_position``) are one inline SSV parameter set bound at the system
level with hierarchical names (``actuator_pt.servo_bandwidth``), as SSP 1.0 specifies for
system bindings. ``DefaultExperiment`` holds the run's start and stop time; SSP 1.0 has no
field for the communication step, so it (the model's sample period) and the master's
settings are in the annotation.

The portable set-up (:func:`write_portable_ssp`, written by ``validate`` as
``cosimulation_portable.ssp``) is the same experiment for engines that only connect outputs to
inputs (libcosim, ECOS, run by :mod:`lpvpc.validation.engines`): a record-player FMU
(:func:`build_record_fmu`) plays the commands and the measured UT torque and computes the PT - UT
position and the PT load; every connection joins two elements; the actuators' parameters are
bound on their components (parameter set ``initialValues``); step sizes are in the OSP
annotations both engines read (``osp:StepSizeHint`` per component, ``osp:FixedStepAlgorithm``
base step in ``DefaultExperiment``).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import asdict

import numpy as np
from pathlib import Path

from lpvpc.errors import FMUError
from lpvpc.io.outputs import atomic_path

from .cosim import ACTUATOR_OUTPUTS, MODEL_OUTPUTS, CosimSettings, connections
from .fmu import FMUInfo, inspect_fmu

__all__ = ["write_ssp", "ssp_connections", "instance_parameters", "SSD_NAMESPACES", "ANNOTATION_TYPE",
           "write_portable_ssp", "build_record_fmu", "portable_ssp_from_run", "PORTABLE_CONNECTIONS"]

SSD_NAMESPACES = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
}
LPVPC_NAMESPACE = "urn:lpvpc:cosimulation"
ANNOTATION_TYPE = "org.lpvpc.cosimulation"
SSP_VERSION = "1.0"

#: FMU resource of each instance the master creates (component name -> resource stem);
#: the names are those :func:`lpvpc.validation.cosim.connections` uses.
_RESOURCES = {"actuator_ut": "actuator", "actuator_pt": "actuator", "model": "model"}
#: The outputs the master reads from each role (:mod:`lpvpc.validation.cosim`).
_OUTPUTS = {"actuator": ACTUATOR_OUTPUTS, "model": MODEL_OUTPUTS}
_DIRECT = re.compile(r"^(\w+)\.(\w+)(?: \((?P<note>[^()]*)\))?$")
# FMI 2 / FMI 3 variable types -> SSP 1.0 connector types
_SSC_TYPES = {"Real": "Real", "Float64": "Real", "Float32": "Real", "Integer": "Integer", "Int32": "Integer",
              "Enumeration": "Enumeration", "Boolean": "Boolean", "String": "String"}

for _prefix, _uri in {**SSD_NAMESPACES, "lpvpc": LPVPC_NAMESPACE}.items():
    ET.register_namespace(_prefix, _uri)


def _q(prefix: str, tag: str) -> str:
    return f"{{{SSD_NAMESPACES[prefix] if prefix != 'lpvpc' else LPVPC_NAMESPACE}}}{tag}"


def _fmt(x: float) -> str:
    return repr(float(x))


def ssp_connections(settings: CosimSettings | None = None, signals=(), wiring=None) -> list[dict]:
    """The experiment's wiring in SSP terms: ``wiring``, the master's (input, source) pairs
    (``CosimResult.connections`` of a run), default :func:`lpvpc.validation.cosim.connections`
    of ``settings`` and ``signals``. One dict
    per input of an instance with ``end`` (component, connector), ``kind`` ("component":
    from another instance's output, ``start`` its (component, connector); "system": from
    the system input connector ``start`` (None, name); "constant": unconnected) and
    ``source`` (the master's description of the signal). A constant source is a system
    input connector too (``kind`` "constant", ``value`` its value, bound as a parameter).

    With the default settings only the UT actuator's position reaches the model as a
    component output (the scheduling, rad); the perturbation position PT - UT (rad) and
    its derivatives are computed by the master, so they are system inputs. With the
    one-step ``load="model"`` set-up the model torque (N m) loads the PT actuator directly
    and the unloaded UT actuator's load is the constant 0:

    >>> from lpvpc.validation.cosim import CosimSettings
    >>> for c in ssp_connections():
    ...     print(".".join(c["end"]), "<-", c["kind"], c["start"][1])
    actuator_ut.command <- system actuator_ut_command
    actuator_pt.command <- system actuator_pt_command
    actuator_ut.load_torque <- system actuator_ut_load_torque
    actuator_pt.load_torque <- system actuator_pt_load_torque
    model.position <- system model_position
    model.scheduling <- component position
    model.velocity <- system model_velocity
    model.acceleration <- system model_acceleration
    >>> {".".join(c["end"]): c["start"] for c in ssp_connections(CosimSettings(load="model"))
    ...  if c["kind"] != "system"}
    {'actuator_ut.load_torque': (None, 'actuator_ut_load_torque'), 'actuator_pt.load_torque': ('model', 'torque'), 'model.scheduling': ('actuator_ut', 'position')}
    """
    settings = (settings or CosimSettings()).check()
    out = []
    for target, source in (wiring if wiring is not None else connections(settings, tuple(signals))):
        end = tuple(target.split(".", 1))
        m = _DIRECT.match(source)
        if m and m.group(1) in _RESOURCES and m.group(2) in _OUTPUTS[_RESOURCES[m.group(1)]]:
            out.append({"end": end, "kind": "component", "start": (m.group(1), m.group(2)), "source": source})
        elif source.strip() == "0":
            # a system input bound to 0, not an unconnected input: fmpy 0.3.32's simulate_ssp
            # wires an unconnected input to the previous input's source
            out.append({"end": end, "kind": "constant", "start": (None, f"{end[0]}_{end[1]}"), "value": 0.0,
                        "source": source})
        else:
            out.append({"end": end, "kind": "system", "start": (None, f"{end[0]}_{end[1]}"), "source": source})
    return out


def instance_parameters(actuator_parameters: dict, command_ut0: float, command_pt0: float) -> dict:
    """Parameters of each actuator instance as :func:`lpvpc.validation.cosim.run_cosimulation`
    sets them: the shared ``actuator_parameters`` plus ``initial_position`` at the first
    command of the instance's run."""
    return {"actuator_ut": {**actuator_parameters, "initial_position": float(command_ut0)},
            "actuator_pt": {**actuator_parameters, "initial_position": float(command_pt0)}}


def _variables(info: FMUInfo) -> dict:
    """name -> fmpy ScalarVariable of the inputs, outputs and parameters."""
    return {v.name: v for v in info.model_description.modelVariables
            if v.causality in ("input", "output", "parameter")}


def _unit(v) -> str | None:
    if v.unit:
        return v.unit
    declared = getattr(v, "declaredType", None)
    return getattr(declared, "unit", None) if declared is not None else None


def _type_element(parent, v, prefix="ssc"):
    kind = _SSC_TYPES.get(v.type)
    if kind is None:
        raise FMUError(f"variable '{v.name}' has type {v.type}, which SSP 1.0 connectors cannot carry")
    el = ET.SubElement(parent, _q(prefix, kind))
    unit = _unit(v)
    if kind == "Real" and unit:
        el.set("unit", unit)
    return el


def _connector(parent, name, kind, v):
    c = ET.SubElement(parent, _q("ssd", "Connector"), name=name, kind=kind)
    _type_element(c, v)
    return c


def _units(infos) -> list:
    seen = {}
    for info in infos:
        for u in info.model_description.unitDefinitions or []:
            if u.name and u.name not in seen:
                seen[u.name] = u
    return list(seen.values())


def _add_component(elements, name: str, source: str, variables: dict, parameters, step: float):
    """One FMU component of an SSD: its connectors (every variable of ``variables``, {name:
    fmpy ScalarVariable}), its parameter bindings (``parameters``, {name: value}, units from the
    variables) and the OSP step-size hint ``step`` (s) that libcosim reads."""
    el = ET.SubElement(elements, _q("ssd", "Component"), name=name, type="application/x-fmu-sharedlibrary",
                       source=source)
    conns = ET.SubElement(el, _q("ssd", "Connectors"))
    for v in variables.values():
        _connector(conns, v.name, v.causality, v)
    if parameters:
        bindings = ET.SubElement(el, _q("ssd", "ParameterBindings"))
        values = ET.SubElement(ET.SubElement(bindings, _q("ssd", "ParameterBinding")), _q("ssd", "ParameterValues"))
        pset = ET.SubElement(values, _q("ssv", "ParameterSet"), version=SSP_VERSION, name=PARAMETER_SET)
        params = ET.SubElement(pset, _q("ssv", "Parameters"))
        for p, value in parameters.items():
            real = ET.SubElement(ET.SubElement(params, _q("ssv", "Parameter"), name=p), _q("ssv", "Real"),
                                 value=_fmt(value))
            unit = _unit(variables[p])
            if unit:
                real.set("unit", unit)
    ann = ET.SubElement(ET.SubElement(el, _q("ssd", "Annotations")), _q("ssc", "Annotation"), type=OSP_ANNOTATION)
    ET.SubElement(ann, f"{{{OSP_NAMESPACE}}}StepSizeHint", value=_fmt(step))
    return el


def _write_units(root, infos) -> None:
    """The SSD's ``Units``: every unit the FMUs define, with its SI base-unit exponents."""
    units = _units(infos)
    if not units:
        return
    el = ET.SubElement(root, _q("ssd", "Units"))
    for u in units:
        unit = ET.SubElement(el, _q("ssc", "Unit"), name=u.name)
        base = ET.SubElement(unit, _q("ssc", "BaseUnit"))
        b = u.baseUnit
        if b is not None:
            for key in ("kg", "m", "s", "A", "K", "mol", "cd", "rad"):
                if getattr(b, key):
                    base.set(key, str(int(getattr(b, key))))
            if b.factor != 1.0:
                base.set("factor", _fmt(b.factor))
            if b.offset != 0.0:
                base.set("offset", _fmt(b.offset))


def _ssd(fmus: dict, settings: CosimSettings, parameters: dict, signals, start_time: float, stop_time: float,
         communication_step: float, name: str, master_wiring) -> bytes:
    wiring = ssp_connections(settings, signals, master_wiring)
    variables = {role: _variables(info) for role, info in fmus.items()}
    var_of = {comp: variables[role] for comp, role in _RESOURCES.items()}

    # every wired name must exist in the FMU with the causality the master uses it with
    for w in wiring:
        comp, var = w["end"]
        v = var_of[comp].get(var)
        if v is None or v.causality != "input":
            raise FMUError(f"{_RESOURCES[comp]} FMU {fmus[_RESOURCES[comp]].path}: no input '{var}' for "
                           f"{comp}.{var}")
        if w["kind"] == "component":
            s_comp, s_var = w["start"]
            sv = var_of[s_comp].get(s_var)
            if sv is None or sv.causality != "output":
                raise FMUError(f"{_RESOURCES[s_comp]} FMU {fmus[_RESOURCES[s_comp]].path}: no output '{s_var}' "
                               f"for {s_comp}.{s_var}")
    for comp, values in parameters.items():
        for p in values:
            v = var_of.get(comp, {}).get(p)
            if v is None or v.causality != "parameter":
                raise FMUError(f"{comp}: no parameter named '{p}' in {fmus[_RESOURCES[comp]].path}")

    root = ET.Element(_q("ssd", "SystemStructureDescription"), version=SSP_VERSION, name=name,
                      generationTool="lpvpc validation.ssp")
    system = ET.SubElement(root, _q("ssd", "System"), name=name,
                           description="Lab experiment of lpvpc validate: two actuator instances run the UT and PT "
                                       "commands, the model FMU plays the ankle and loads the PT actuator")
    sys_inputs = [w for w in wiring if w["kind"] in ("system", "constant")]
    if sys_inputs:
        conns = ET.SubElement(system, _q("ssd", "Connectors"))
        for w in sys_inputs:
            comp, var = w["end"]
            c = _connector(conns, w["start"][1], "input", var_of[comp][var])
            c.set("description", w["source"])
    # TSystem order: Connectors, ParameterBindings, Elements, Connections, Annotations
    constants = [w for w in wiring if w["kind"] == "constant"]
    if parameters or constants:
        bindings = ET.SubElement(system, _q("ssd", "ParameterBindings"))
        binding = ET.SubElement(bindings, _q("ssd", "ParameterBinding"))
        values = ET.SubElement(binding, _q("ssd", "ParameterValues"))
        pset = ET.SubElement(values, _q("ssv", "ParameterSet"), version=SSP_VERSION, name="harness")
        params = ET.SubElement(pset, _q("ssv", "Parameters"))
        for comp, vals in parameters.items():
            for p, value in vals.items():
                par = ET.SubElement(params, _q("ssv", "Parameter"), name=f"{comp}.{p}")
                real = ET.SubElement(par, _q("ssv", "Real"), value=_fmt(value))
                unit = _unit(var_of[comp][p])
                if unit:
                    real.set("unit", unit)
        for w in constants:
            par = ET.SubElement(params, _q("ssv", "Parameter"), name=w["start"][1])
            ET.SubElement(par, _q("ssv", "Real"), value=_fmt(w["value"]))
    elements = ET.SubElement(system, _q("ssd", "Elements"))
    for comp, role in _RESOURCES.items():
        el = ET.SubElement(elements, _q("ssd", "Component"), name=comp, type="application/x-fmu-sharedlibrary",
                           source=f"resources/{role}.fmu")
        conns = ET.SubElement(el, _q("ssd", "Connectors"))
        for v in var_of[comp].values():
            _connector(conns, v.name, v.causality, v)
    links = ET.SubElement(system, _q("ssd", "Connections"))
    for w in wiring:
        s_comp, s_var = w["start"]
        attrs = {"startConnector": s_var, "endElement": w["end"][0], "endConnector": w["end"][1]}
        if s_comp is not None:
            attrs = {"startElement": s_comp, **attrs}
        ET.SubElement(links, _q("ssd", "Connection"), **attrs)
    annotations = ET.SubElement(system, _q("ssd", "Annotations"))
    note = ET.SubElement(annotations, _q("ssc", "Annotation"), type=ANNOTATION_TYPE)
    master = ET.SubElement(note, _q("lpvpc", "Master"), communicationStep=_fmt(communication_step),
                           actuatorStep=_fmt(fmus["actuator"].step_size or communication_step),
                           **{k: str(v) for k, v in asdict(settings).items()})
    for w in wiring:
        ET.SubElement(master, _q("lpvpc", "Signal"), input=".".join(w["end"]), kind=w["kind"], source=w["source"])

    _write_units(root, fmus.values())
    ET.SubElement(root, _q("ssd", "DefaultExperiment"), startTime=_fmt(start_time), stopTime=_fmt(stop_time))
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def write_ssp(path, model_fmu, actuator_fmu, *, stop_time: float, communication_step: float,
              settings: CosimSettings | None = None, parameters: dict | None = None, signals=(),
              start_time: float = 0.0, name: str = "lpvpc_cosimulation", wiring=None) -> Path:
    """Write the co-simulation set-up as an SSP 1.0 archive at ``path`` and return it.

    ``model_fmu``, ``actuator_fmu``: FMU paths or :class:`lpvpc.validation.fmu.FMUInfo` (a path is
    checked with :func:`lpvpc.validation.fmu.inspect_fmu`: a missing or corrupt FMU raises
    :class:`lpvpc.errors.FMUError`). ``parameters``: instance -> {parameter: value}, as
    :func:`instance_parameters` gives them; ``signals``: an extended model's extra input
    names (fed from the record); ``wiring``: the run's own connections
    (``CosimResult.connections``; default those of ``settings``). ``stop_time``,
    ``communication_step`` in s.
    """
    fmus = {"model": model_fmu if isinstance(model_fmu, FMUInfo) else inspect_fmu(model_fmu, "model FMU"),
            "actuator": actuator_fmu if isinstance(actuator_fmu, FMUInfo) else inspect_fmu(actuator_fmu,
                                                                                         "actuator FMU")}
    for role, info in fmus.items():
        if not info.path.is_file():
            raise FMUError(f"{role} FMU {info.path}: file not found")
    if not (stop_time > start_time and communication_step > 0):
        raise ValueError(f"need stop_time > start_time and communication_step > 0, got {start_time}, {stop_time}, "
                         f"{communication_step}")
    ssd = _ssd(fmus, (settings or CosimSettings()).check(), parameters or {}, tuple(signals), start_time,
               stop_time, communication_step, name, wiring)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # write next to the target and rename, so a reader never sees half an archive
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("SystemStructure.ssd", ssd)
            for role, info in fmus.items():
                zf.write(info.path, f"resources/{role}.fmu")
    return path


# ---------------------------------------------------------------------------------------
# The portable set-up: connections between elements only, every harness signal in an FMU

#: OSP annotation namespace (libcosim and ECOS read component step sizes and the base step from it).
OSP_NAMESPACE = "http://opensimulationplatform.com/SSP/OSPAnnotations"
OSP_ANNOTATION = "com.opensimulationplatform"
#: Name of every component parameter set (ECOS applies a set by name: ``init(parameter_set=...)``;
#: libcosim applies each component's first set).
PARAMETER_SET = "initialValues"
RECORD_OUTPUTS = ("command_ut", "command_pt", "load_ut", "load_pt", "perturbation")
RECORD_INPUTS = ("pt_position", "ut_position", "model_torque", "pt_velocity", "ut_velocity", "pt_acceleration",
                 "ut_acceleration")
ET.register_namespace("osp", OSP_NAMESPACE)


def record_source_dir() -> Path:
    """Folder with ``record_system.c``, the record-player system of the portable SSP."""
    from lpvpc.export.fmu_build import wrapper_dir

    return wrapper_dir().parent / "record"


def build_record_fmu(path, command_ut, command_pt, torque_ut, step: float) -> Path:
    """The record-player FMU (FMI 2.0 co-simulation, step ``step`` s) of the portable SSP:
    plays the commands (rad) and the measured UT torque (N m), one sample per step, and
    computes the harness's signals from the inputs it took at the start of the last step:
    ``perturbation``, the PT - UT position one step ahead (second-order Taylor from the
    actuators' velocities and accelerations, so the model gets the difference at its own
    sample time, as in the harness) (rad) and ``load_pt = torque_ut + model_torque`` (N m).
    No output depends on the current inputs, so an engine that passes values in dependency
    order within a communication point (OMSimulator) and one that passes them after every
    step (libcosim, ECOS) give it the same values. The record is compiled into the FMU
    (``record_table.h`` in its sources)."""
    import tempfile

    from lpvpc.export.fmu_build import FmuVariable, build_fmu

    arrays = {n: np.asarray(a, dtype=float).ravel() for n, a in
              (("rec_command_ut", command_ut), ("rec_command_pt", command_pt), ("rec_torque_ut", torque_ut))}
    n = {len(a) for a in arrays.values()}
    if len(n) != 1 or min(n) < 1 or not all(np.isfinite(a).all() for a in arrays.values()):
        raise FMUError(f"record FMU: commands and UT torque must be finite and of one length, got "
                       f"{[len(a) for a in arrays.values()]}")
    outputs = [FmuVariable("command_ut", "output", "rad", "UT actuator command of the record", dependencies=[]),
               FmuVariable("command_pt", "output", "rad", "PT actuator command of the record", dependencies=[]),
               FmuVariable("load_ut", "output", "N.m", "measured UT torque of the record", dependencies=[]),
               FmuVariable("load_pt", "output", "N.m", "measured UT torque + model_torque taken at the start "
                           "of the last step", dependencies=[]),
               FmuVariable("perturbation", "output", "rad",
                           "PT - UT position one step ahead: d + h dv + h^2/2 da (d, dv, da: PT - UT position, "
                           "velocity, acceleration taken at the start of the last step; h the step)",
                           dependencies=[])]
    inputs = [FmuVariable("pt_position", "input", "rad", "PT actuator position", 0.0),
              FmuVariable("ut_position", "input", "rad", "UT actuator position", 0.0),
              FmuVariable("model_torque", "input", "N.m", "model torque", 0.0),
              FmuVariable("pt_velocity", "input", "rad/s", "PT actuator velocity", 0.0),
              FmuVariable("ut_velocity", "input", "rad/s", "UT actuator velocity", 0.0),
              FmuVariable("pt_acceleration", "input", "rad/s2", "PT actuator acceleration", 0.0),
              FmuVariable("ut_acceleration", "input", "rad/s2", "UT actuator acceleration", 0.0)]
    with tempfile.TemporaryDirectory(prefix="lpvpc-record-") as tmp:
        table = Path(tmp) / "record_table.h"
        with open(table, "w") as f:
            f.write(f"/* generated by lpvpc.validation.ssp.build_record_fmu: the record, one sample per "
                    f"{step!r} s */\n#define REC_N {min(n)}L\n")
            for name, a in arrays.items():
                f.write(f"static const double {name}[{len(a)}] = {{\n")
                f.write(",\n".join(float(v).hex() for v in a))
                f.write("};\n")
        return build_fmu(path, model_identifier="lpvpc_record", system_sources=[
            record_source_dir() / "record_system.c", table], nx=3, step_size=float(step), outputs=outputs,
            inputs=inputs, parameters=[], fmi_version=2,
            description="Record player of the lpvpc validation set-up: commands and measured UT torque of the "
                        "record, and the harness's signals (PT - UT position, UT torque + model torque)")


#: (end component, connector) <- (start component, connector) of the portable set-up.
PORTABLE_CONNECTIONS = (
    (("actuator_ut", "command"), ("record", "command_ut")),
    (("actuator_pt", "command"), ("record", "command_pt")),
    (("actuator_ut", "load_torque"), ("record", "load_ut")),
    (("actuator_pt", "load_torque"), ("record", "load_pt")),
    (("record", "pt_position"), ("actuator_pt", "position")),
    (("record", "ut_position"), ("actuator_ut", "position")),
    (("record", "model_torque"), ("model", "torque")),
    (("record", "pt_velocity"), ("actuator_pt", "velocity")),
    (("record", "ut_velocity"), ("actuator_ut", "velocity")),
    (("record", "pt_acceleration"), ("actuator_pt", "acceleration")),
    (("record", "ut_acceleration"), ("actuator_ut", "acceleration")),
    (("model", "position"), ("record", "perturbation")),
    (("model", "scheduling"), ("actuator_ut", "position")),
)


def write_portable_ssp(path, model_fmu, actuator_fmu, record_fmu, *, stop_time: float, parameters: dict,
                       start_time: float = 0.0, name: str = "lpvpc_portable") -> Path:
    """The validation set-up as an SSP 1.0 archive that libcosim and ECOS run as it is.

    Four components: ``record`` (:func:`build_record_fmu`: commands, measured UT torque, PT - UT
    position, UT torque + model torque), ``actuator_ut``, ``actuator_pt`` and ``model``;
    connections between elements only (:data:`PORTABLE_CONNECTIONS`); each component's
    parameters (``parameters[component]``: the actuators' calibrated servo and
    ``initial_position``) bound on the component as an inline parameter set named
    ``PARAMETER_SET``; each component's step size (its FMU's DefaultExperiment step) in an
    ``osp:StepSizeHint`` annotation and the base step (the smallest) in the DefaultExperiment's
    ``osp:FixedStepAlgorithm`` annotation, where libcosim and ECOS read them; start and stop
    time in ``DefaultExperiment``. Paths or :class:`lpvpc.validation.fmu.FMUInfo`; ``stop_time`` s.
    """
    fmus = {}
    for role, f in (("model", model_fmu), ("actuator", actuator_fmu), ("record", record_fmu)):
        fmus[role] = f if isinstance(f, FMUInfo) else inspect_fmu(f, f"{role} FMU")
        if fmus[role].fmi_version != 2:
            raise FMUError(f"{role} FMU {fmus[role].path.name}: the portable SSP takes FMI 2.0 FMUs (libcosim "
                           "runs FMI 1 and 2 only)")
    roles = {"record": "record", "actuator_ut": "actuator", "actuator_pt": "actuator", "model": "model"}
    var_of = {comp: _variables(fmus[role]) for comp, role in roles.items()}
    for (e_comp, e_var), (s_comp, s_var) in PORTABLE_CONNECTIONS:
        for comp, var, want in ((e_comp, e_var, "input"), (s_comp, s_var, "output")):
            v = var_of[comp].get(var)
            if v is None or v.causality != want:
                raise FMUError(f"{roles[comp]} FMU {fmus[roles[comp]].path.name}: no {want} '{var}' for {comp}.{var}")
    for comp, vals in parameters.items():
        for p in vals:
            v = var_of.get(comp, {}).get(p)
            if v is None or v.causality != "parameter":
                raise FMUError(f"{comp}: no parameter named '{p}'")
    steps = {comp: float(fmus[role].step_size) for comp, role in roles.items()}
    if not all(s > 0 for s in steps.values()) or not stop_time > start_time:
        raise ValueError(f"need step sizes > 0 and stop_time > start_time, got {steps}, {start_time}, {stop_time}")
    base = min(steps.values())

    root = ET.Element(_q("ssd", "SystemStructureDescription"), version=SSP_VERSION, name=name,
                      generationTool="lpvpc validation.ssp")
    system = ET.SubElement(root, _q("ssd", "System"), name=name,
                           description="Lab experiment of lpvpc validate: the record player drives two actuator "
                                       "instances with the UT and PT commands; the model FMU plays the ankle on "
                                       "their position difference and loads the PT actuator")
    elements = ET.SubElement(system, _q("ssd", "Elements"))
    files = {}
    for comp, role in roles.items():
        files[f"resources/{role}.fmu"] = fmus[role].path
        _add_component(elements, comp, f"resources/{role}.fmu", var_of[comp], parameters.get(comp), steps[comp])
    links = ET.SubElement(system, _q("ssd", "Connections"))
    for (e_comp, e_var), (s_comp, s_var) in PORTABLE_CONNECTIONS:
        ET.SubElement(links, _q("ssd", "Connection"), startElement=s_comp, startConnector=s_var,
                      endElement=e_comp, endConnector=e_var)
    _write_units(root, fmus.values())
    de = ET.SubElement(root, _q("ssd", "DefaultExperiment"), startTime=_fmt(start_time), stopTime=_fmt(stop_time))
    ann = ET.SubElement(ET.SubElement(de, _q("ssd", "Annotations")), _q("ssc", "Annotation"), type=OSP_ANNOTATION)
    ET.SubElement(ET.SubElement(ann, f"{{{OSP_NAMESPACE}}}Algorithm"), f"{{{OSP_NAMESPACE}}}FixedStepAlgorithm",
                  baseStepSize=_fmt(base))
    ET.indent(root)
    ssd = ET.tostring(root, encoding="UTF-8", xml_declaration=True)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("SystemStructure.ssd", ssd)
            for arc, src in files.items():
                zf.write(src, arc)
    return path


def portable_ssp_from_run(path, model_fmu, actuator_fmu, drive, parameters: dict, settings: CosimSettings,
                          latency: int, record_fmu_path) -> Path | None:
    """Write the portable SSP of a harness run (:func:`write_portable_ssp`) at ``path`` and its
    record-player FMU at ``record_fmu_path``; returns ``path``, or None when the run cannot be
    expressed with connections alone (an FMI 3.0 model FMU: libcosim runs FMI 2 only; a model FMU
    with inputs other than ``position`` and ``scheduling``, e.g. an extended model's record
    signals; a load setting other than the default ``measured_ut+model``).

    ``drive``: the run's :class:`lpvpc.validation.cosim.ActuatorDrive`; ``parameters``:
    :func:`instance_parameters`; ``latency``: the exact model FMU's latency in model steps (the
    record continues that long with everything held, as in the harness)."""
    from .cosim import hold_tail

    model = model_fmu if isinstance(model_fmu, FMUInfo) else inspect_fmu(model_fmu, "model FMU")
    inputs = tuple(v.name for v in model.model_description.modelVariables if v.causality == "input")
    if model.fmi_version != 2 or inputs != ("position", "scheduling") or settings.load != "measured_ut+model":
        return None
    r, K = drive.ratio, drive.n_model
    cu, cp, lu = (np.asarray(x[:K * r], dtype=float) for x in (drive.command_ut, drive.command_pt, drive.load_ut))
    if settings.command_rate == "hold":
        idx = (np.arange(K * r) // r) * r
        cu, cp = cu[idx], cp[idx]
    cu, cp, lu = (hold_tail(x, latency * r) for x in (cu, cp, lu))
    record = build_record_fmu(record_fmu_path, cu, cp, lu, drive.step)
    return write_portable_ssp(path, model, actuator_fmu, record, stop_time=(K + latency) * r * drive.step,
                              parameters=parameters)
