"""Build FMI 2.0 / 3.0 co-simulation FMUs from a fixed-step discrete-time system in C.

A system provides the three C functions of ``lpvpc/export/c/wrapper/system.h``::

    int sys_initial_state(const double *p, double *x);                         /* x0(p) */
    int sys_output(const double *x, const double *u, const double *p, double *y);  /* y = g(x, u, p) */
    int sys_update(const double *x, const double *u, const double *p, double *x_next);  /* x+ = f(x, u, p) */

:func:`build_fmu` generates ``system_config.h`` and ``modelDescription.xml``, compiles the
generic wrapper (``fmi2_cs.c`` or ``fmi3_cs.c``, both including the shared core ``cs_core.h``)
with the system sources into
``binaries/linux64/<id>.so`` (FMI 2) or ``binaries/x86_64-linux/<id>.so`` (FMI 3), ships all C
sources and headers in ``sources/`` (FMI 2: ``<SourceFiles>``; FMI 3:
``sources/buildDescription.xml``) so that ``fmpy compile`` can rebuild the binary, and zips
the result.

Value references (both FMI versions): 0 = time (FMI 3 only), outputs 1..NY, inputs
NY+1..NY+NU, parameters after. Parameters are ``fixed``: settable before and during
initialization only. Units are SI; every unit used gets a ``UnitDefinitions`` entry with its
SI base-unit exponents (see :data:`UNITS`).

Two timing modes (``ticks_per_sample``): direct (outputs g(x, u, p) of the inputs of the
current communication point; the actuator) and sampled (the system is sampled every
``step_size`` s, communication steps are multiples of a base tick, outputs are those of the
last processed sample, held; the exported models; semantics in ``lpvpc/export/c/wrapper/cs_core.h``).

The output latency of a model has no standard field: the caller declares it as a constant
output (``constants``, value references after the parameters; lpvpc.export.exporter adds ``latency``
and ``sample_period``), and it is also written into the description text and a vendor
annotation (FMI 2 ``VendorAnnotations/Tool[@name='lpvpc']/Latency``, FMI 3
``Annotations/Annotation[@type='lpvpc']/Latency``).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass
from math import isfinite, pi
from pathlib import Path
from typing import Sequence

from lpvpc.errors import ExportError
from lpvpc.io.outputs import atomic_path, signals_held

__all__ = [
    "FmuVariable",
    "UNITS",
    "build_fmu",
    "fmi_headers_dir",
    "wrapper_dir",
    "fmu_guid",
]

#: SI base-unit exponents (FMI ``BaseUnit`` attributes) of the units the builder knows.
UNITS: dict[str, dict[str, float]] = {
    "1": {},
    "s": {"s": 1},
    "Hz": {"s": -1},
    "rad": {"rad": 1},
    "deg": {"rad": 1, "factor": pi / 180.0},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "m": {"m": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "kg": {"kg": 1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "kg.m2": {"kg": 1, "m": 2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "N.m/rad2": {"kg": 1, "m": 2, "s": -2, "rad": -2},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "N.m.s2/rad": {"kg": 1, "m": 2, "rad": -1},
    "N.m/(rad/s)": {"kg": 1, "m": 2, "s": -1, "rad": -1},
}

_CAUSALITIES = ("input", "output", "parameter")
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_FMI2_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
_FMI3_HEADERS = ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
_BASE_CFLAGS = ("-O2", "-std=c99", "-shared", "-fPIC", "-fvisibility=hidden", "-Wall", "-Wextra")
_LDFLAGS = ("-Wl,--no-undefined", "-lm")
#: Internal steps one doStep may take: the FMU's declared maximum communication step is
#: MAX_STEPS * step_size (stated in the model description); a longer step is an error, so
#: one call's work stays bounded (milliseconds to seconds, never hours).
MAX_STEPS = 1_000_000


@dataclass
class FmuVariable:
    """One scalar FMU variable (all variables are Real / Float64).

    ``dependencies`` (outputs only): names of the inputs the output depends on directly
    (direct feedthrough); ``None`` = unknown, declared as depending on every input. Getting
    it right matters to masters that break algebraic loops (an output declared independent
    of an input can be fed back into that input without an iteration).
    """

    name: str
    causality: str  # 'input' | 'output' | 'parameter'
    unit: str = ""
    description: str = ""
    start: float = 0.0
    dependencies: Sequence[str] | None = None


# ----------------------------------------------------------------------------- locations


def wrapper_dir() -> Path:
    """Folder with ``system.h``, ``cs_core.h``, ``fmi2_cs.c`` and ``fmi3_cs.c``.

    ``$LPVPC_FMU_MODELS/wrapper`` if that variable is set, else the C sources that ship as
    package data in ``lpvpc/export/c``.

    >>> sorted(p.name for p in wrapper_dir().glob("fmi*_cs.c"))
    ['fmi2_cs.c', 'fmi3_cs.c']
    """
    root = os.environ.get("LPVPC_FMU_MODELS")
    if root:
        base = Path(root)
    else:
        base = Path(__file__).resolve().parent / "c"
    d = base / "wrapper"
    if not (d / "system.h").is_file():
        raise ExportError(
            f"FMU wrapper sources not found in {d} (set LPVPC_FMU_MODELS to a folder of lpvpc's FMU C sources)"
        )
    return d


def fmi_headers_dir() -> Path:
    """The FMI 2 / FMI 3 C headers shipped with fmpy (``<fmpy>/c-code``)."""
    try:
        import fmpy
    except ImportError as exc:  # pragma: no cover - fmpy is a dependency
        raise ExportError("fmpy is needed for the FMI headers (pip install fmpy)") from exc
    d = Path(fmpy.__file__).resolve().parent / "c-code"
    missing = [h for h in _FMI2_HEADERS + _FMI3_HEADERS if not (d / h).is_file()]
    if missing:
        raise ExportError(f"FMI headers missing in {d}: {', '.join(missing)}")
    return d


def _platform_dir(fmi_version: int) -> str:
    if sys.platform.startswith("linux") and os.uname().machine in ("x86_64", "AMD64"):
        return "linux64" if fmi_version == 2 else "x86_64-linux"
    raise ExportError(
        f"building FMU binaries is implemented for x86_64 Linux only, not {sys.platform}/{os.uname().machine}"
    )


# ----------------------------------------------------------------------------- checks


def _check_inputs(model_identifier, system_sources, nx, step_size, outputs, inputs, parameters,
                  fmi_version, latency, ticks_per_sample=0, constants=()):
    problems = []
    if not isinstance(ticks_per_sample, int) or ticks_per_sample < 0:
        problems.append(f"ticks_per_sample must be an integer >= 0, not {ticks_per_sample!r}")
    if not isinstance(model_identifier, str) or not _NAME_RE.match(model_identifier):
        problems.append(f"model_identifier {model_identifier!r} is not a C identifier")
    if fmi_version not in (2, 3):
        problems.append(f"fmi_version must be 2 or 3, not {fmi_version!r}")
    if not isinstance(nx, int) or nx < 0:
        problems.append(f"nx must be an integer >= 0, not {nx!r}")
    try:
        step_ok = float(step_size) > 0 and isfinite(float(step_size))
    except (TypeError, ValueError):
        step_ok = False
    if not step_ok:
        problems.append(f"step_size must be a finite number > 0 s, not {step_size!r}")
    if latency is not None and not (isfinite(float(latency)) and float(latency) >= 0):
        problems.append(f"latency must be None or a finite number >= 0 s, not {latency!r}")
    if not system_sources:
        problems.append("system_sources is empty")
    for src in system_sources:
        if not Path(src).is_file():
            problems.append(f"system source {src} does not exist")
    if not outputs:
        problems.append("an FMU needs at least one output")
    seen = set()
    groups = (("output", outputs), ("input", inputs), ("parameter", parameters), ("output", constants))
    input_names = {v.name for v in inputs}
    for expected, variables in groups:
        for v in variables:
            if not isinstance(v, FmuVariable):
                problems.append(f"{v!r} is not an FmuVariable")
                continue
            if not _NAME_RE.match(v.name or ""):
                problems.append(f"variable name {v.name!r} is not a C-style identifier")
            if v.name == "time":
                problems.append("variable name 'time' is reserved for the independent variable")
            if v.name in seen:
                problems.append(f"variable name {v.name!r} is used twice")
            seen.add(v.name)
            if v.causality != expected:
                problems.append(f"variable {v.name!r} has causality {v.causality!r} but is listed as {expected}")
            if v.unit and v.unit not in UNITS:
                problems.append(f"variable {v.name!r}: unknown unit {v.unit!r} (known: {', '.join(UNITS)})")
            try:
                if not isfinite(float(v.start)):
                    problems.append(f"variable {v.name!r}: start value {v.start!r} is not finite")
            except (TypeError, ValueError):
                problems.append(f"variable {v.name!r}: start value {v.start!r} is not a number")
            if v.dependencies is not None:
                if expected != "output":
                    problems.append(f"variable {v.name!r}: only outputs have dependencies")
                else:
                    for d in v.dependencies:
                        if d not in input_names:
                            problems.append(f"output {v.name!r} depends on {d!r}, which is not an input")
    if problems:
        raise ExportError("cannot build FMU: " + "; ".join(problems))


# ----------------------------------------------------------------------------- generation


def _c_string(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _c_doubles(values) -> str:
    values = [repr(float(v)) for v in values]
    return "{" + ", ".join(values or ["0.0"]) + "}"


def _c_strings(names) -> str:
    return "{" + ", ".join([_c_string(n) for n in names] or ['""']) + "}"


def _system_config(guid, model_identifier, nx, step_size, outputs, inputs, parameters, ticks_per_sample=0,
                   constants=()) -> str:
    sampled = "" if not ticks_per_sample else (
        f"#define SYS_TICKS_PER_SAMPLE {int(ticks_per_sample)} /* sampled mode: base ticks per sample period */\n")
    const = "" if not constants else (
        f"#define SYS_NC {len(constants)}\n#define SYS_CONST_VALUES {_c_doubles(v.start for v in constants)}\n"
        f"#define SYS_CONST_NAMES {_c_strings(v.name for v in constants)}\n")
    return f"""/* system_config.h -- generated by lpvpc.export.fmu_build for {model_identifier}; do not edit. */
#ifndef LPVPC_SYSTEM_CONFIG_H
#define LPVPC_SYSTEM_CONFIG_H

#define SYS_NX {nx}
#define SYS_NU {len(inputs)}
#define SYS_NY {len(outputs)}
#define SYS_NP {len(parameters)}
#define SYS_STEP {float(step_size)!r} /* internal fixed step, s */
#define SYS_MAX_STEPS {MAX_STEPS} /* internal steps per doStep at most (the maximum communication step) */
#define SYS_GUID {_c_string(guid)}
#define SYS_MODEL_IDENTIFIER {_c_string(model_identifier)}
#define SYS_PARAM_DEFAULTS {_c_doubles(v.start for v in parameters)}
#define SYS_INPUT_DEFAULTS {_c_doubles(v.start for v in inputs)}
#define SYS_OUTPUT_NAMES {_c_strings(v.name for v in outputs)}
#define SYS_INPUT_NAMES {_c_strings(v.name for v in inputs)}
#define SYS_PARAM_NAMES {_c_strings(v.name for v in parameters)}
{sampled}{const}
#endif /* LPVPC_SYSTEM_CONFIG_H */
"""


def _fmt(x: float) -> str:
    return repr(float(x))


def _full_description(description: str, latency: float | None, step_size: float, ticks_per_sample=0) -> str:
    text = description.strip()
    if ticks_per_sample:
        tick = float(step_size) / ticks_per_sample
        extra = (f"Sampled every {_fmt(step_size)} s; communication steps are whole numbers of the base "
                 f"tick {_fmt(tick)} s, at most {_fmt(MAX_STEPS * tick)} s ({MAX_STEPS} ticks), or end between "
                 "ticks (the outputs are held until the next).")
    else:
        extra = (f"Fixed internal step {_fmt(step_size)} s; communication steps are whole numbers of it, "
                 f"at most {_fmt(MAX_STEPS * float(step_size))} s ({MAX_STEPS} internal steps), or end between "
                 "internal steps (the step that starts on the grid takes the inputs; the outputs are held until "
                 "the next grid point).")
    if latency is not None:
        if latency == 0:
            extra += " Output latency: 0 s (no added delay)."
        else:
            extra += f" Output latency: {_fmt(latency)} s (outputs are delayed by this time)."
    return f"{text} {extra}".strip()


def _set_state_capabilities(element, fmi2: bool) -> None:
    """The capabilities the CoSimulation and ModelExchange elements share (both wrappers get,
    set and serialize the FMU state and give no derivatives), in the standard's attribute order."""
    if fmi2:
        flags = (("canNotUseMemoryManagementFunctions", "false"), ("canGetAndSetFMUstate", "true"),
                 ("canSerializeFMUstate", "true"), ("providesDirectionalDerivative", "false"))
    else:
        flags = (("canGetAndSetFMUState", "true"), ("canSerializeFMUState", "true"),
                 ("providesDirectionalDerivatives", "false"), ("providesAdjointDerivatives", "false"),
                 ("providesPerElementDependencies", "false"))
    for name, value in flags:
        element.set(name, value)


def _model_description(guid, *, model_identifier, fmi_version, step_size, outputs, inputs, parameters,
                       description, version, author, generation_tool, latency, c_sources, ticks_per_sample=0,
                       constants=()) -> bytes:
    fmi2 = fmi_version == 2
    tick = float(step_size) / ticks_per_sample if ticks_per_sample else float(step_size)
    units = sorted({v.unit for v in (*outputs, *inputs, *parameters, *constants) if v.unit})
    if not fmi2:
        units = sorted(set(units) | {"s"})  # the time variable
    root = ET.Element("fmiModelDescription")
    root.set("fmiVersion", "2.0" if fmi2 else "3.0")
    root.set("modelName", model_identifier)
    root.set("guid" if fmi2 else "instantiationToken", guid)
    root.set("description", _full_description(description, latency, step_size, ticks_per_sample))
    if author:
        root.set("author", author)
    if version:
        root.set("version", version)
    root.set("generationTool", generation_tool)
    root.set("variableNamingConvention", "flat")
    if fmi2:
        root.set("numberOfEventIndicators", "0")

    cs = ET.SubElement(root, "CoSimulation")
    cs.set("modelIdentifier", model_identifier)
    cs.set("needsExecutionTool", "false")
    cs.set("canHandleVariableCommunicationStepSize", "true")
    cs.set("canBeInstantiatedOnlyOncePerProcess", "false")
    if fmi2:
        cs.set("canInterpolateInputs", "false")
        cs.set("maxOutputDerivativeOrder", "0")
        cs.set("canRunAsynchronuously", "false")
        _set_state_capabilities(cs, fmi2)
        files = ET.SubElement(cs, "SourceFiles")
        for name in c_sources:
            ET.SubElement(files, "File").set("name", name)
    else:
        _set_state_capabilities(cs, fmi2)
        cs.set("fixedInternalStepSize", _fmt(tick))
        cs.set("maxOutputDerivativeOrder", "0")
        cs.set("providesIntermediateUpdate", "false")
        cs.set("mightReturnEarlyFromDoStep", "false")
        cs.set("canReturnEarlyAfterIntermediateUpdate", "false")
        cs.set("hasEventMode", "false")
        cs.set("providesEvaluateDiscreteStates", "false")

    if units:
        ud = ET.SubElement(root, "UnitDefinitions")
        for name in units:
            u = ET.SubElement(ud, "Unit")
            u.set("name", name)
            b = ET.SubElement(u, "BaseUnit")
            for key, val in UNITS[name].items():
                b.set(key, _fmt(val) if key == "factor" else str(int(val)))

    cats = ET.SubElement(root, "LogCategories")
    for name, text in (("logStatusError", "Errors: wrong calls, non-finite values, failed system functions"),
                       ("logStatusWarning", "Warnings"),
                       ("logAll", "Informative messages (only with logging on)")):
        c = ET.SubElement(cats, "Category")
        c.set("name", name)
        c.set("description", text)

    de = ET.SubElement(root, "DefaultExperiment")
    de.set("startTime", "0.0")
    de.set("stepSize", _fmt(tick))

    def latency_annotation():
        lat_text = ("Output delay in seconds introduced by the model realisation (no standard FMI field; "
                    "0 = none)")
        if fmi2:
            tool = ET.SubElement(ET.SubElement(root, "VendorAnnotations"), "Tool")
            tool.set("name", "lpvpc")
        else:
            tool = ET.SubElement(ET.SubElement(root, "Annotations"), "Annotation")
            tool.set("type", "lpvpc")
        lat = ET.SubElement(tool, "Latency")
        lat.set("seconds", _fmt(latency))
        lat.set("description", lat_text)

    if latency is not None and fmi2:  # FMI 2: before ModelVariables
        latency_annotation()

    mv = ET.SubElement(root, "ModelVariables")
    # ModelStructure refers to variables by 1-based position in ModelVariables (FMI 2) or by
    # value reference (FMI 3); the layout makes both k + 1 (FMI 3's time is vr 0, not listed there).
    ref = {}
    ordered = [("output", v) for v in outputs] + [("input", v) for v in inputs] + \
              [("parameter", v) for v in parameters] + [("constant", v) for v in constants]
    if not fmi2:
        t = ET.SubElement(mv, "Float64")
        t.set("name", "time")
        t.set("valueReference", "0")
        t.set("causality", "independent")
        t.set("variability", "continuous")
        t.set("description", "Simulation time")
        t.set("unit", "s")
    for k, (causality, v) in enumerate(ordered):
        ref[v.name] = k + 1
        variability = {"parameter": "fixed", "constant": "constant"}.get(causality, "continuous")
        if ticks_per_sample and causality == "output":
            variability = "discrete"  # held between sample times
        constant = causality == "constant"
        causality = "output" if constant else causality
        # FMI 2 puts start/unit on a <Real> child of <ScalarVariable>; FMI 3 on <Float64> itself.
        el = ET.SubElement(mv, "ScalarVariable" if fmi2 else "Float64")
        el.set("name", v.name)
        el.set("valueReference", str(k + 1))
        if v.description:
            el.set("description", v.description)
        el.set("causality", causality)
        el.set("variability", variability)
        if causality == "output":
            el.set("initial", "exact" if constant else "calculated")
        typed = ET.SubElement(el, "Real") if fmi2 else el
        if causality != "output" or constant:
            typed.set("start", _fmt(v.start))
        if v.unit:
            typed.set("unit", v.unit)

    ms = ET.SubElement(root, "ModelStructure")

    def unknown(parent, tag, v, with_deps):
        e = ET.SubElement(parent, tag)
        e.set("index" if fmi2 else "valueReference", str(ref[v.name]))
        if with_deps and v.dependencies is not None:
            deps = [str(ref[d]) for d in v.dependencies]
            e.set("dependencies", " ".join(deps))
            if deps:
                e.set("dependenciesKind", " ".join(["dependent"] * len(deps)))

    if fmi2:
        outs = ET.SubElement(ms, "Outputs")
        for v in (*outputs, *constants):
            unknown(outs, "Unknown", v, True)
        inits = ET.SubElement(ms, "InitialUnknowns")
        for v in outputs:
            unknown(inits, "Unknown", v, False)
    else:
        for v in (*outputs, *constants):
            unknown(ms, "Output", v, True)
        for v in outputs:
            unknown(ms, "InitialUnknown", v, False)
        if latency is not None:  # FMI 3: after ModelStructure
            latency_annotation()

    ET.indent(root, space="  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


#: FMI interface types :func:`build_fmu` can build: co-simulation, Model Exchange.
INTERFACES = ("cs", "me")


def _interface_description(xml: bytes, interface: str) -> bytes:
    """The co-simulation model description turned into Model Exchange for ``interface="me"``:
    a ``ModelExchange`` element with the same identifier and capabilities, outputs ``discrete``
    (a sampled model changes them at its time events only), and a description that states the
    time events instead of communication steps."""
    if interface == "cs":
        return xml
    root = ET.fromstring(xml)
    fmi2 = root.get("fmiVersion") == "2.0"
    cs = root.find("CoSimulation")
    index = list(root).index(cs)
    me = ET.Element("ModelExchange")
    me.set("modelIdentifier", cs.get("modelIdentifier"))
    me.set("needsExecutionTool", "false")
    me.set("canBeInstantiatedOnlyOncePerProcess", "false")
    if fmi2:
        me.set("completedIntegratorStepNotNeeded", "true")
        _set_state_capabilities(me, fmi2)
        me.append(cs.find("SourceFiles"))
    else:
        _set_state_capabilities(me, fmi2)
        me.set("needsCompletedIntegratorStep", "false")
        me.set("providesEvaluateDiscreteStates", "false")
    root.remove(cs)
    root.insert(index, me)
    step = root.find("DefaultExperiment").get("stepSize")
    text = root.get("description", "")
    text = re.sub(r"Fixed internal step \S+ s; communication steps are whole numbers of it, .*?grid point\)\.",
                  f"Model Exchange, sampled: one time event every {step} s (at start time + k {step} s); "
                  "the inputs set at t_k, before or after its event, are sample k's; outputs change only there.",
                  text)
    root.set("description", text)
    for v in root.find("ModelVariables"):
        if v.get("causality") == "output":
            v.set("variability", "discrete")
    ET.indent(root, space="  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


def _definitions(extra_cflags) -> list[tuple[str, str | None]]:
    """``-DNAME[=VALUE]`` flags as (name, value) pairs, for buildDescription.xml."""
    out = []
    for flag in extra_cflags:
        if flag.startswith("-D") and len(flag) > 2:
            name, _, value = flag[2:].partition("=")
            out.append((name, value if "=" in flag else None))
    return out


def _build_description(model_identifier: str, c_sources: list[str], extra_cflags=()) -> bytes:
    root = ET.Element("fmiBuildDescription")
    root.set("fmiVersion", "3.0")
    bc = ET.SubElement(root, "BuildConfiguration")
    bc.set("modelIdentifier", model_identifier)
    bc.set("description", "gcc -O2 -std=c99 -shared -fPIC -fvisibility=hidden *.c -lm")
    sfs = ET.SubElement(bc, "SourceFileSet")
    sfs.set("language", "C99")
    for name in c_sources:
        ET.SubElement(sfs, "SourceFile").set("name", name)
    for name, value in _definitions(extra_cflags):
        d = ET.SubElement(sfs, "PreprocessorDefinition")
        d.set("name", name)
        if value is not None:
            d.set("value", value)
    lib = ET.SubElement(bc, "Library")
    lib.set("name", "m")
    lib.set("external", "true")
    lib.set("description", "C math library (may be needed by generated model code)")
    ET.indent(root, space="  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


def _collect_sources(fmi_version, system_sources, include_dirs, interface="cs") -> dict[str, Path]:
    """name in sources/ -> file to copy (the generated config is added later)."""
    wdir = wrapper_dir()
    hdir = fmi_headers_dir()
    files: dict[str, Path] = {}

    def add(path: Path, what: str):
        path = Path(path)
        if path.name in files and files[path.name].resolve() != path.resolve():
            raise ExportError(f"two source files named {path.name!r} ({files[path.name]} and {path}, {what}): "
                              "sources/ is flat, rename one")
        files[path.name] = path

    add(wdir / f"fmi{fmi_version}_{interface}.c", "wrapper")
    if interface == "me":
        add(wdir / "me_core.h", "wrapper")
    add(wdir / "system.h", "wrapper")
    add(wdir / "cs_core.h", "wrapper")  # included by the wrapper: shipped, not listed as a source file
    if fmi_version == 3:
        add(wdir / "fmi3_stubs.h", "wrapper")  # the functions both FMI 3 wrappers answer alike
    for h in _FMI2_HEADERS if fmi_version == 2 else _FMI3_HEADERS:
        add(hdir / h, "FMI header")
    for src in system_sources:
        if Path(src).name in ("system_config.h", "buildDescription.xml"):
            raise ExportError(f"{src}: the name {Path(src).name!r} is reserved for a generated file")
        add(Path(src), "system source")
    for d in include_dirs:
        d = Path(d)
        if not d.is_dir():
            raise ExportError(f"include directory {d} does not exist")
        for h in sorted(d.glob("*.h")):
            add(h, f"header from {d}")
    return files


def _hash_inputs(files: dict[str, Path], parts: Sequence[str | bytes]) -> str:
    h = hashlib.sha256()
    h.update(Path(__file__).read_bytes())  # a change of the builder changes the GUID
    for name in sorted(files):
        h.update(name.encode())
        h.update(b"\0")
        h.update(files[name].read_bytes())
        h.update(b"\0")
    for p in parts:
        h.update(p if isinstance(p, bytes) else p.encode())
        h.update(b"\0")
    d = h.hexdigest()
    return "{" + f"{d[0:8]}-{d[8:12]}-{d[12:16]}-{d[16:20]}-{d[20:32]}" + "}"


def _plan(model_identifier, system_sources, nx, step_size, outputs, inputs, parameters, fmi_version,
          description, version, author, include_dirs, extra_cflags, latency, generation_tool, interface="cs",
          ticks_per_sample=0, constants=()):
    _check_inputs(model_identifier, system_sources, nx, step_size, outputs, inputs, parameters,
                  fmi_version, latency, ticks_per_sample, constants)
    if interface not in INTERFACES:
        raise ExportError(f"unknown FMI interface {interface!r}; choose one of {INTERFACES}")
    files = _collect_sources(fmi_version, system_sources, include_dirs, interface)
    c_sources = sorted(n for n in files if n.endswith(".c"))
    md_args = dict(model_identifier=model_identifier, fmi_version=fmi_version, step_size=float(step_size),
                   outputs=list(outputs), inputs=list(inputs), parameters=list(parameters),
                   description=description, version=version, author=author,
                   generation_tool=generation_tool, latency=None if latency is None else float(latency),
                   c_sources=c_sources, ticks_per_sample=ticks_per_sample, constants=list(constants))
    # everything that ends up in the FMU except the GUID itself
    probe = "{GUID}"
    parts = [
        _system_config(probe, model_identifier, nx, step_size, outputs, inputs, parameters, ticks_per_sample,
                       constants),
        _interface_description(_model_description(probe, **md_args), interface),
        " ".join(_BASE_CFLAGS + tuple(extra_cflags) + _LDFLAGS),
    ]
    guid = _hash_inputs(files, parts)
    md_args["interface"] = interface
    return guid, files, c_sources, md_args


def fmu_guid(**kwargs) -> str:
    """The GUID / instantiation token :func:`build_fmu` would give for these arguments
    (same keyword arguments, without ``fmu_path``)."""
    defaults = dict(fmi_version=2, description="", version="", author="lpvpc", include_dirs=(),
                    extra_cflags=(), latency=None, generation_tool="lpvpc")
    defaults.update(kwargs)
    guid, *_ = _plan(**defaults)
    return guid


def _existing_guid(fmu_path: Path) -> str | None:
    try:
        with zipfile.ZipFile(fmu_path) as zf:
            root = ET.fromstring(zf.read("modelDescription.xml"))
    except (OSError, KeyError, zipfile.BadZipFile, ET.ParseError):
        return None
    return root.get("guid") or root.get("instantiationToken")


# ----------------------------------------------------------------------------- build


def _compile(cmd, workdir, timeout) -> subprocess.CompletedProcess:
    """Run the compiler in its own process group with its temporary files in ``workdir``.
    On any exception (timeout, Ctrl-C, SIGTERM) the whole group (driver, cc1, as, ld) is
    stopped before the exception goes on, so nothing writes into a folder being removed."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "TMPDIR": str(workdir)})
    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException:
        for sig, wait in ((signal.SIGTERM, 5.0), (signal.SIGKILL, None)):  # SIGTERM: gcc removes its files
            try:
                os.killpg(proc.pid, sig)
                proc.wait(timeout=wait)
                break
            except subprocess.TimeoutExpired:
                continue
            except ProcessLookupError:
                break
        proc.wait()
        _wait_for_group(proc.pid)
        raise
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def _wait_for_group(pgid: int, timeout: float = 5.0) -> None:
    """Wait until no live process of group ``pgid`` is left: the driver can exit before cc1
    and as, which would otherwise still write into the folder being removed (seen under
    load as 'Directory not empty' from the build folder's clean-up). SIGKILL after
    ``timeout`` s; zombies (which write nothing) do not count."""
    deadline = time.monotonic() + timeout
    killed = False
    while _group_alive(pgid):
        if time.monotonic() > deadline:
            if killed:
                return
            killed = True
            deadline += 1.0
            try:
                os.killpg(pgid, signal.SIGKILL)
            except OSError:
                return
        time.sleep(0.01)


def _group_alive(pgid: int) -> bool:
    """A process of group ``pgid`` that is not a zombie exists (Linux: /proc/PID/stat)."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":  # fields: state, ppid, pgrp, ...
            return True
    return False


def check_built_fmu(folder, model_identifier: str) -> None:
    """Check an unpacked FMU before it is written: fmpy loads its shared library, which must
    export every FMI function of its interface (``fmi2Instantiate``, ``fmi2DoStep``, ... or
    ``fmi3InstantiateCoSimulation``, ...), and instantiates it once. Raises
    :class:`~lpvpc.errors.ExportError` naming what failed."""
    from fmpy import instantiate_fmu, read_model_description

    try:
        md = read_model_description(str(folder), validate=False)
        fmu = instantiate_fmu(str(folder), md)
    except Exception as exc:  # noqa: BLE001 - fmpy raises plain Exceptions (missing symbol, NULL instance)
        raise ExportError(f"the compiled FMU {model_identifier} is not usable (missing FMI functions or "
                          f"instantiation failed): {' '.join(str(exc).split())}") from None
    try:
        fmu.freeInstance()
    finally:
        fmu.freeLibrary()


def build_fmu(fmu_path, *, model_identifier: str, system_sources: list[Path], nx: int, step_size: float,
              outputs: list[FmuVariable], inputs: list[FmuVariable], parameters: list[FmuVariable],
              fmi_version: int = 2, description: str = "", version: str = "", author: str = "lpvpc",
              include_dirs: list[Path] = (), extra_cflags: list[str] = (), latency: float | None = None,
              generation_tool: str = "lpvpc", reuse_existing: bool = False,
              timings: dict | None = None, interface: str = "cs", ticks_per_sample: int = 0,
              constants: Sequence[FmuVariable] = ()) -> Path:
    """Build an FMU (FMI 2.0 or 3.0) around a fixed-step discrete-time C system.

    Parameters
    ----------
    fmu_path : str or pathlib.Path
        The ``.fmu`` to write (parent folders are created; written atomically).
    model_identifier : str
        C identifier; the name of the shared library and of the model.
    system_sources : list of pathlib.Path
        C files (and headers) implementing ``system.h``; ``.c`` files are compiled, everything
        is copied to ``sources/``.
    nx : int
        Number of states of the system.
    step_size : float
        Internal fixed step in s; communication steps are whole numbers of it, or end between
        internal steps (outputs held until the next). Also the ``DefaultExperiment`` step size.
    outputs, inputs, parameters : list of FmuVariable
        The variables, in value-reference order (module docstring).
    fmi_version : int, default 2
        2 or 3.
    description, version, author, generation_tool : str
        Written into the model description.
    include_dirs : list of pathlib.Path, optional
        Folders whose top-level ``*.h`` files the system sources include (copied to the flat
        ``sources/`` folder; file names must be unique).
    extra_cflags : list of str, optional
        More compiler flags (after the defaults). ``-DNAME[=VALUE]`` flags are also written to
        FMI 3's ``buildDescription.xml``; FMI 2 has no place for them, so a rebuild from
        ``sources/`` needs them in a header instead.
    latency : float or None, default None
        Output delay of the model in s (None: not stated); written into the description and
        a vendor annotation.
    reuse_existing : bool, default False
        If ``fmu_path`` exists and carries the GUID these arguments produce (same sources,
        settings and builder), return it without rebuilding.
    timings : dict or None, default None
        If given, receives ``generate``, ``compile``, ``package`` and ``total`` times in s,
        ``reused`` (bool) and ``compiler_output`` (gcc's warnings).
    interface : {"cs", "me"}, default "cs"
        Co-simulation, or Model Exchange: the same system as a sampled-data model with a
        time event every ``step_size`` s (wrapper ``fmi2_me.c`` / ``fmi3_me.c`` over
        ``me_core.h``; outputs discrete, no continuous states).
    ticks_per_sample : int, default 0
        0: direct mode (outputs g(x, u, p) of the current inputs); N >= 1: sampled mode (the
        system is sampled every ``step_size`` s, communication steps are multiples of the base
        tick ``step_size / N``, the DefaultExperiment step; outputs are those of the last
        processed sample; ``lpvpc/export/c/wrapper/cs_core.h``).
    constants : list of FmuVariable, optional
        Constant outputs (``causality="output"``, ``start`` = the value), e.g. a declared
        latency in s; value references after the parameters.

    Returns
    -------
    pathlib.Path
        The path of the FMU.

    Raises
    ------
    lpvpc.errors.ExportError
        Bad arguments, a missing compiler or header, or a compiler error (with the
        compiler's message).
    """
    t0 = time.perf_counter()
    fmu_path = Path(fmu_path)
    target = fmu_path.absolute()  # the compiler gets absolute paths: a name starting with '-' is no option
    guid, files, c_sources, md_args = _plan(
        model_identifier, system_sources, nx, step_size, outputs, inputs, parameters, fmi_version,
        description, version, author, include_dirs, extra_cflags, latency, generation_tool, interface,
        ticks_per_sample, constants)
    if reuse_existing and fmu_path.is_file() and _existing_guid(fmu_path) == guid:
        if timings is not None:
            timings.update(generate=time.perf_counter() - t0, compile=0.0, package=0.0,
                           total=time.perf_counter() - t0, reused=True, compiler_output="")
        return fmu_path

    cc = os.environ.get("CC", "gcc")
    if shutil.which(cc) is None:
        raise ExportError(f"C compiler {cc!r} not found (install gcc or set CC)")
    platform_dir = _platform_dir(fmi_version)
    target.parent.mkdir(parents=True, exist_ok=True)

    with signals_held():  # a signal cannot fall between creating the build folder and owning it
        build_dir = tempfile.TemporaryDirectory(prefix=f".{model_identifier}-", dir=target.parent)
    with build_dir as tmp:
        stage = Path(tmp).absolute() / "fmu"
        src_dir = stage / "sources"
        bin_dir = stage / "binaries" / platform_dir
        src_dir.mkdir(parents=True)
        bin_dir.mkdir(parents=True)
        for name, path in files.items():
            shutil.copyfile(path, src_dir / name)
        (src_dir / "system_config.h").write_text(
            _system_config(guid, model_identifier, nx, step_size, outputs, inputs, parameters, ticks_per_sample,
                           constants))
        interface = md_args.pop("interface")
        (stage / "modelDescription.xml").write_bytes(
            _interface_description(_model_description(guid, **md_args), interface))
        if fmi_version == 3:
            (src_dir / "buildDescription.xml").write_bytes(
                _build_description(model_identifier, c_sources, extra_cflags))
        t_gen = time.perf_counter()

        library = bin_dir / f"{model_identifier}.so"
        cmd = [cc, *_BASE_CFLAGS, f"-I{src_dir}", f"-I{fmi_headers_dir()}", *extra_cflags,
               *[str(src_dir / n) for n in c_sources], "-o", str(library), *_LDFLAGS]
        try:
            proc = _compile(cmd, tmp, timeout=600)
        except subprocess.TimeoutExpired as exc:
            raise ExportError(f"compiling {model_identifier} timed out after {exc.timeout} s") from exc
        if proc.returncode != 0 or not library.is_file():
            raise ExportError(
                f"compiling {model_identifier} failed (exit status {proc.returncode}):\n"
                f"$ {' '.join(cmd)}\n{proc.stderr.strip()}")
        check_built_fmu(stage, model_identifier)
        t_cc = time.perf_counter()

        with atomic_path(target) as tmp_fmu, zipfile.ZipFile(tmp_fmu, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            for path in sorted(p for p in stage.rglob("*") if p.is_file()):
                zf.write(path, path.relative_to(stage).as_posix())
        t_end = time.perf_counter()

    if timings is not None:
        timings.update(generate=t_gen - t0, compile=t_cc - t_gen, package=t_end - t_cc, total=t_end - t0,
                       reused=False, compiler_output=proc.stderr.strip())
    return fmu_path
