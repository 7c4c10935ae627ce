"""The co-simulation set-up as an SSP 1.0 archive (System Structure and Parameterization),
so that other tools can load the components, connections and parameters the harness uses.

Units: time s, angles rad, torque N m (the FMUs' own units are copied into the SSD).

The archive (:func:`write_ssp`) is a zip with ``SystemStructure.ssd`` at its root and the
FMUs under ``resources/``: one component per FMU instance of :func:`validation.cosim.run_cosimulation`
(``actuator_ut`` and ``actuator_pt`` share ``resources/actuator.fmu``; ``model`` is
``resources/model.fmu``), each with a connector for every input, output and parameter of
its model description (name, kind and type as declared there).

The connections are those of :func:`validation.cosim.connections` for the given settings:

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
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import asdict
from pathlib import Path

from lpvpc.errors import FMUError
from lpvpc.outputs import atomic_path

from .cosim import ACTUATOR_OUTPUTS, MODEL_OUTPUTS, CosimSettings, connections
from .fmu import FMUInfo, inspect_fmu

__all__ = ["write_ssp", "ssp_connections", "instance_parameters", "SSD_NAMESPACES", "ANNOTATION_TYPE"]

SSD_NAMESPACES = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
}
LPVPC_NAMESPACE = "urn:lpvpc:cosimulation"
ANNOTATION_TYPE = "org.lpvpc.cosimulation"
SSP_VERSION = "1.0"

#: FMU resource of each instance the master creates (component name -> resource stem);
#: the names are those :func:`validation.cosim.connections` uses.
_RESOURCES = {"actuator_ut": "actuator", "actuator_pt": "actuator", "model": "model"}
#: The outputs the master reads from each role (:mod:`validation.cosim`).
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
    (``CosimResult.connections`` of a run), default :func:`validation.cosim.connections`
    of ``settings`` and ``signals``. One dict
    per input of an instance with ``end`` (component, connector), ``kind`` ("component":
    from another instance's output, ``start`` its (component, connector); "system": from
    the system input connector ``start`` (None, name); "constant": unconnected) and
    ``source`` (the master's description of the signal). A constant source is a system
    input connector too (``kind`` "constant", ``value`` its value, bound as a parameter)."""
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
    """Parameters of each actuator instance as :func:`validation.cosim.run_cosimulation`
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

    units = _units(fmus.values())
    if units:
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
    ET.SubElement(root, _q("ssd", "DefaultExperiment"), startTime=_fmt(start_time), stopTime=_fmt(stop_time))
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def write_ssp(path, model_fmu, actuator_fmu, *, stop_time: float, communication_step: float,
              settings: CosimSettings | None = None, parameters: dict | None = None, signals=(),
              start_time: float = 0.0, name: str = "lpvpc_cosimulation", wiring=None) -> Path:
    """Write the co-simulation set-up as an SSP 1.0 archive at ``path`` and return it.

    ``model_fmu``, ``actuator_fmu``: FMU paths or :class:`validation.fmu.FMUInfo` (a path is
    checked with :func:`validation.fmu.inspect_fmu`: a missing or corrupt FMU raises
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
