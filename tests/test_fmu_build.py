"""The generic FMI co-simulation wrapper (lpvpc/export/c/wrapper) and the builder (lpvpc.export.fmu_build).

The actuator (lpvpc/export/c/actuator) is the system under the wrapper, plus a tiny test system
that can fail on purpose. Units: SI. Every wrong call must return an error status and log a
message that names the problem, never crash.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
from fmpy.fmi3 import FMU3Slave
from fmpy.validation import validate_fmu
import fmpy

from lpvpc.export.actuator import ACTUATOR_DEFAULTS, actuator_build_kwargs, actuator_source_dir, build_actuator_fmu
from lpvpc.errors import ExportError
from lpvpc.export.fmu_build import FmuVariable, build_fmu, fmi_headers_dir, fmu_guid

# value references of the actuator (outputs 1..3, inputs 4..5, parameters 6..11)
POS, VEL, ACC, CMD, LOAD = 1, 2, 3, 4, 5
PARAM = {name: 6 + i for i, name in enumerate(ACTUATOR_DEFAULTS)}


# ----------------------------------------------------------------------------- driver


class Slave:
    """A thin driver over fmpy's FMU2Slave / FMU3Slave that collects log messages."""

    def __init__(self, unzipdir, md, name="inst", guid=None):
        self.version = 2 if md.fmiVersion == "2.0" else 3
        self.logs: list[tuple[int, str]] = []
        cls = FMU2Slave if self.version == 2 else FMU3Slave
        self.fmu = cls(guid=guid or md.guid, unzipDirectory=str(unzipdir),
                       modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        if self.version == 2:
            def log2(env, instance, status, category, message):
                self.logs.append((status, message.decode()))
            self._cb = fmi2CallbackFunctions()
            self._cb.logger = fmi2CallbackLoggerTYPE(log2)
            self._cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
            self._cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
            self._log2 = log2
            self.fmu.instantiate(callbacks=self._cb)
        else:
            def log3(env, status, category, message):
                self.logs.append((status, message.decode()))
            self.fmu.instantiate(logMessage=log3)

    # --- common calls -------------------------------------------------------------
    def init(self, start=0.0, **params):
        self.enter_init(start)
        if params:
            self.set([PARAM[k] for k in params], list(params.values()))
        self.fmu.exitInitializationMode()

    def enter_init(self, start=0.0):
        if self.version == 2:
            self.fmu.setupExperiment(startTime=start)
            self.fmu.enterInitializationMode()
        else:
            self.fmu.enterInitializationMode(startTime=start)

    def get(self, vrs):
        return (self.fmu.getReal if self.version == 2 else self.fmu.getFloat64)(list(vrs))

    def set(self, vrs, values):
        (self.fmu.setReal if self.version == 2 else self.fmu.setFloat64)(list(vrs), list(values))

    def step(self, t, h):
        self.fmu.doStep(t, h)

    def free(self):
        self.fmu.freeInstance()

    def expect_error(self, func, *args, contains: str | tuple[str, ...]):
        """func(*args) must fail with an error status and log a message containing `contains`."""
        n = len(self.logs)
        with pytest.raises(FMICallException) as info:
            func(*args)
        assert info.value.status >= 3, info.value  # fmi2Error / fmi3Error
        new = " | ".join(m for _, m in self.logs[n:])
        for text in (contains,) if isinstance(contains, str) else contains:
            assert text in new, f"expected {text!r} in the log, got: {new!r}"
        return new


def _open(fmu_path, tmp_path_factory):
    md = read_model_description(str(fmu_path))
    unzipdir = extract(str(fmu_path), unzipdir=str(tmp_path_factory.mktemp("unzip")))
    return md, unzipdir


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """{2: path, 3: path} of actuator FMUs built for this module, plus build timings."""
    out = tmp_path_factory.mktemp("fmus")
    timings = {}
    paths = {}
    for v in (2, 3):
        t = {}
        paths[v] = build_actuator_fmu(out / f"actuator{v}.fmu", fmi_version=v, timings=t)
        timings[v] = t
    paths["timings"] = timings
    return paths


@pytest.fixture(scope="module")
def opened(fmus, tmp_path_factory):
    return {v: _open(fmus[v], tmp_path_factory) for v in (2, 3)}


def new_slave(opened, version, name="inst"):
    md, unzipdir = opened[version]
    return Slave(unzipdir, md, name)


# ----------------------------------------------------------------------------- builder


def test_build_times_are_reported(fmus):
    for v in (2, 3):
        t = fmus["timings"][v]
        assert t["total"] >= t["compile"] > 0
        assert t["compiler_output"] == "", t["compiler_output"]  # -Wall -Wextra clean


@pytest.mark.parametrize("version", [2, 3])
def test_fmpy_validation_is_empty(fmus, version):
    assert validate_fmu(str(fmus[version])) == []


def _fmutool():
    exe = shutil.which("fmutool") or str(Path(sys.executable).with_name("fmutool"))
    return exe if Path(exe).exists() else None


@pytest.mark.parametrize("version", [2, 3])
def test_fmutool_check_passes(fmus, version):
    exe = _fmutool()
    if exe is None:
        pytest.skip("fmutool (fmu-manipulation-toolbox, in the 'test' extra) is not installed")
    proc = subprocess.run([exe, "-input", str(fmus[version]), "-check"], capture_output=True, text=True,
                          timeout=120)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert f"compliant with FMI-{version}.0" in out, out
    assert "No semantic error" in out, out
    assert "ERROR" not in out.upper().replace("NO SEMANTIC ERROR", ""), out


@pytest.mark.parametrize("version", [2, 3])
def test_model_description_contents(fmus, version):
    md = read_model_description(str(fmus[version]))
    cs = md.coSimulation
    assert cs.canHandleVariableCommunicationStepSize
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    assert not cs.needsExecutionTool
    assert float(md.defaultExperiment.stepSize) == 1e-3
    units = {u.name for u in md.unitDefinitions}
    used = {v.unit for v in md.modelVariables if v.unit}
    assert used <= units and {"rad", "rad/s", "rad/s2", "N.m", "kg.m2", "N.m/rad", "Hz"} <= units
    vrs = {v.name: v.valueReference for v in md.modelVariables}
    if version == 3:
        assert vrs["time"] == 0
    assert [vrs[n] for n in ("position", "velocity", "acceleration", "command", "load_torque")] == [1, 2, 3, 4, 5]
    params = [v for v in md.modelVariables if v.causality == "parameter"]
    assert all(v.variability == "fixed" for v in params)
    assert "Output latency: 0 s" in md.description
    with zipfile.ZipFile(fmus[version]) as zf:
        names = set(zf.namelist())
        xml = zf.read("modelDescription.xml").decode()
    assert 'Latency seconds="0.0"' in xml
    plat = "linux64" if version == 2 else "x86_64-linux"
    assert f"binaries/{plat}/lpvpc_actuator.so" in names
    expected = {"sources/system.h", "sources/system_config.h", "sources/actuator.c",
                f"sources/fmi{version}_cs.c", f"sources/fmi{version}Functions.h"}
    assert expected <= names
    if version == 3:
        assert "sources/buildDescription.xml" in names
    else:
        assert "<SourceFiles>" in xml
    # dependencies: position/velocity have no direct feedthrough, acceleration depends on load_torque
    outputs = {u.variable.name: u for u in md.outputs}
    assert outputs["position"].dependencies == [] and outputs["velocity"].dependencies == []
    assert [d.name for d in outputs["acceleration"].dependencies] == ["load_torque"]


def test_only_fmi_symbols_are_exported(fmus, tmp_path):
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("nm (binutils) not installed")
    for v in (2, 3):
        d = tmp_path / f"x{v}"
        extract(str(fmus[v]), unzipdir=str(d))
        lib = next(d.glob("binaries/*/*.so"))
        out = subprocess.run([nm, "-D", "--defined-only", str(lib)], capture_output=True, text=True,
                             check=True).stdout
        names = [line.split()[-1] for line in out.splitlines() if line.strip()]
        assert names and all(n.startswith(f"fmi{v}") for n in names), names
        undefined = subprocess.run([nm, "-D", "--undefined-only", str(lib)], capture_output=True, text=True,
                                   check=True).stdout
        assert "sqrt" not in undefined and "exp" not in undefined  # no libm needed by the actuator


def test_guid_is_a_hash_of_sources_and_settings(fmus, tmp_path):
    for v in (2, 3):
        assert fmu_guid(**actuator_build_kwargs(v)) == read_model_description(str(fmus[v])).guid
    kw = actuator_build_kwargs(2)
    g2 = fmu_guid(**kw)
    kw["parameters"][0].start = 41.0
    assert fmu_guid(**kw) != g2
    src = tmp_path / "actuator.c"  # same name, one more character of source
    src.write_text((actuator_source_dir() / "actuator.c").read_text() + "\n")
    assert fmu_guid(**dict(actuator_build_kwargs(2), system_sources=[src])) != g2
    # a second build of unchanged inputs is reused, not recompiled
    t = {}
    build_actuator_fmu(fmus[2], fmi_version=2, timings=t)
    assert t["reused"] is True


@pytest.mark.parametrize("version", [2, 3])
def test_fmpy_compile_rebuilds_the_binary_from_sources(fmus, version, tmp_path):
    if shutil.which("cmake") is None:
        pytest.skip("cmake (needed by fmpy compile) not installed")
    from fmpy.build import build_platform_binary
    from fmpy.util import create_zip_archive

    d = (tmp_path / "x").resolve()
    (tmp_path / "cmake").mkdir()
    extract(str(fmus[version]), unzipdir=str(d))
    shutil.rmtree(d / "binaries")
    build_platform_binary(d, build_dir=tmp_path / "cmake", all_warnings=True,
                          cmake_options={"CMAKE_COMPILE_WARNING_AS_ERROR:BOOL": "ON"})
    assert list((d / "binaries").rglob("lpvpc_actuator.so"))
    rebuilt = tmp_path / "rebuilt.fmu"
    create_zip_archive(str(rebuilt), str(d))

    def run(path):
        md = read_model_description(str(path))
        s = Slave(extract(str(path), unzipdir=str(tmp_path / f"u{path.stem}")), md)
        s.init(initial_position=0.05)
        out, t = [], 0.0
        for k in range(300):
            s.set([CMD, LOAD], [0.05 + 0.1 * math.sin(2 * math.pi * 3 * t), 5.0 * math.cos(7 * t)])
            s.step(t, 0.002)
            t += 0.002
            out.append(s.get([POS, VEL, ACC]))
        s.free()
        return np.array(out)

    a, b = run(fmus[version]), run(rebuilt)
    np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12)


# --- a tiny system that can fail on purpose; NP = 0 exercises empty parameter lists

TINY_C = r"""
#include "system.h"
#ifndef TINY_GAIN
#error "TINY_GAIN must be defined (-DTINY_GAIN=...)"
#endif
/* x+ = x + TINY_GAIN u h; y = [x, 1/x]; sys_update fails (code 7) for u < -1e6 */
int sys_initial_state(const double *p, double *x) { (void)p; x[0] = 1.0; return 0; }
int sys_output(const double *x, const double *u, const double *p, double *y)
{ (void)u; (void)p; y[0] = x[0]; y[1] = 1.0 / x[0]; return 0; }
int sys_update(const double *x, const double *u, const double *p, double *x_next)
{ (void)p; if (u[0] < -1e6) return 7; x_next[0] = x[0] + TINY_GAIN * u[0] * SYS_STEP; return 0; }
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    d = tmp_path_factory.mktemp("tiny")
    src = d / "tiny.c"
    src.write_text(TINY_C)
    kw = dict(model_identifier="tiny", system_sources=[src], nx=1, step_size=0.01,
              outputs=[FmuVariable("x", "output", "rad"), FmuVariable("inv_x", "output", "1")],
              inputs=[FmuVariable("rate", "input", "rad/s")], parameters=[], extra_cflags=["-DTINY_GAIN=1.0"])
    return {v: _open(build_fmu(d / f"tiny{v}.fmu", fmi_version=v, **kw), tmp_path_factory) for v in (2, 3)}


@pytest.mark.parametrize("version", [2, 3])
def test_non_finite_output_is_an_error_and_rolls_back(tiny, version):
    md, unzipdir = tiny[version]
    s = Slave(unzipdir, md)
    s.init()
    s.set([3], [-50.0])  # x: 1 -> 0.5 after one step of 0.01 s
    s.step(0.0, 0.01)
    assert s.get([1, 2]) == [0.5, 2.0]
    # same rate again: x 0.5 -> 0 in the next step, so 1/x = inf
    s.expect_error(s.step, 0.01, 0.01, contains=("inv_x", "not finite"))
    # rolled back to the last good point; further steps refused until reset
    assert s.get([1]) == [0.5]
    s.expect_error(s.step, 0.01, 0.01, contains="illegal call sequence")
    s.fmu.reset()
    s.init()
    assert s.get([1]) == [1.0]
    s.set([3], [-2e6])
    s.expect_error(s.step, 0.0, 0.01, contains="sys_update failed (code 7)")
    s.free()


def test_validation_of_a_system_without_parameters(tiny):
    for v in (2, 3):
        md, unzipdir = tiny[v]
        assert validate_fmu(str(Path(unzipdir))) == []
    # FMI 3: -D flags reach buildDescription.xml (validated against the schema by fmpy)
    md, unzipdir = tiny[3]
    xml = (Path(unzipdir) / "sources" / "buildDescription.xml").read_text()
    assert '<PreprocessorDefinition name="TINY_GAIN" value="1.0" />' in xml
    sfs = md.buildConfigurations[0].sourceFileSets[0]
    assert sorted(sfs.sourceFiles) == ["fmi3_cs.c", "tiny.c"]


def test_compiler_error_raises_export_error_with_message(tmp_path):
    src = tmp_path / "broken.c"
    src.write_text('#include "system.h"\nint sys_initial_state(const double *p, double *x) { return oops; }\n')
    with pytest.raises(ExportError) as info:
        build_fmu(tmp_path / "broken.fmu", model_identifier="broken", system_sources=[src], nx=1,
                  step_size=0.01, outputs=[FmuVariable("y", "output")], inputs=[], parameters=[])
    msg = str(info.value)
    assert "compiling broken failed" in msg and "oops" in msg and "error" in msg
    assert not (tmp_path / "broken.fmu").exists()


def test_missing_system_function_is_caught_at_build_time(tmp_path):
    src = tmp_path / "partial.c"
    src.write_text('#include "system.h"\nint sys_initial_state(const double *p, double *x) { return 0; }\n')
    with pytest.raises(ExportError, match="sys_output"):
        build_fmu(tmp_path / "partial.fmu", model_identifier="partial", system_sources=[src], nx=1,
                  step_size=0.01, outputs=[FmuVariable("y", "output")], inputs=[], parameters=[])


def test_bad_arguments_are_listed(tmp_path):
    src = tmp_path / "s.c"
    src.write_text("")
    with pytest.raises(ExportError) as info:
        build_fmu(tmp_path / "bad.fmu", model_identifier="1bad", system_sources=[src], nx=-1, step_size=0.0,
                  outputs=[FmuVariable("y", "output", "furlong"), FmuVariable("y", "output")],
                  inputs=[FmuVariable("time", "input")], parameters=[FmuVariable("k", "input", start=math.nan)])
    msg = str(info.value)
    for text in ("1bad", "nx", "step_size", "furlong", "used twice", "reserved", "causality", "not finite"):
        assert text in msg, (text, msg)


def test_fmi_headers_dir():
    d = fmi_headers_dir()
    assert (d / "fmi2Functions.h").is_file() and (d / "fmi3Functions.h").is_file()


# ----------------------------------------------------------------------------- wrong calls


@pytest.mark.parametrize("version", [2, 3])
def test_wrong_calls_return_errors_and_log_why(opened, version):
    s = new_slave(opened, version)
    fn = f"fmi{version}"
    s.enter_init()
    s.expect_error(s.step, 0.0, 0.01, contains=(f"{fn}DoStep", "illegal call sequence"))
    s.fmu.exitInitializationMode()
    s.expect_error(s.fmu.exitInitializationMode, contains="illegal call sequence")

    s.expect_error(s.step, 0.5, 0.01, contains="does not match the FMU time")
    s.expect_error(s.step, 0.0, 0.0, contains="must be > 0")
    s.expect_error(s.step, 0.0, -0.01, contains="must be > 0")
    s.expect_error(s.step, 0.0005, 0.001, contains="does not match the FMU time")  # not where the FMU is
    s.expect_error(s.step, 0.0, math.nan, contains="must be finite")

    s.set([CMD], [0.1])
    s.expect_error(s.set, [CMD], [math.nan], contains=("command", "not finite"))
    s.expect_error(s.set, [LOAD], [math.inf], contains=("load_torque", "not finite"))
    s.expect_error(s.set, [CMD, LOAD], [0.3, -math.inf], contains="not finite")
    assert s.get([CMD, LOAD]) == [0.1, 0.0]  # a rejected call changes nothing

    s.expect_error(s.get, [999], contains="unknown value reference 999")
    s.expect_error(s.set, [999], [1.0], contains="unknown value reference 999")
    if version == 2:
        s.expect_error(s.get, [0], contains="unknown value reference 0")
    else:
        assert s.get([0]) == [0.0]  # time
        s.expect_error(s.set, [0], [1.0], contains="'time'")
    s.expect_error(s.set, [POS], [1.0], contains=("position", "cannot be set"))
    s.expect_error(s.set, [PARAM["servo_stiffness"]], [1e3],
                   contains=("servo_stiffness", "fixed parameter", "step mode"))
    if version == 2:
        s.expect_error(s.fmu.getRealOutputDerivatives, [POS], [1], contains="not supported")
        s.expect_error(s.fmu.getInteger, [1], contains="Real variables only")
    else:
        s.expect_error(s.fmu.getOutputDerivatives, [POS], [1], contains="not supported")
        s.expect_error(s.fmu.getInt32, [1], contains="Float64 variables only")
        s.expect_error(s.fmu.enterEventMode, contains="not supported")

    # after all these rejected calls the instance still works normally
    s.step(0.0, 0.01)
    assert all(math.isfinite(v) for v in s.get([POS, VEL, ACC]))
    assert s.get([PARAM["servo_stiffness"]]) == [ACTUATOR_DEFAULTS["servo_stiffness"]]

    s.fmu.terminate()
    s.expect_error(s.step, 0.01, 0.01, contains=(f"{fn}DoStep", "illegal call sequence", "terminated"))
    s.expect_error(s.set, [CMD], [0.2], contains="illegal call sequence")
    s.expect_error(s.fmu.terminate, contains="illegal call sequence")
    # getting values after terminate is allowed by the standard (FMI 2 §4.2.4, FMI 3 state machine)
    assert all(math.isfinite(v) for v in s.get([POS, VEL, ACC]))
    s.free()


@pytest.mark.parametrize("version", [2, 3])
def test_more_illegal_call_orders(opened, version):
    s = new_slave(opened, version)
    s.expect_error(s.get, [POS], contains="illegal call sequence")  # before initialization
    s.expect_error(s.step, 0.0, 0.01, contains="illegal call sequence")
    s.enter_init()
    s.expect_error(s.enter_init, contains="illegal call sequence")
    s.fmu.exitInitializationMode()
    s.free()


@pytest.mark.parametrize("version", [2, 3])
def test_instantiation_with_wrong_guid_fails_with_message(opened, version):
    md, unzipdir = opened[version]
    logs = []
    if version == 2:
        fmu = FMU2Slave(guid="{not-the-guid}", unzipDirectory=str(unzipdir),
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
        cb = fmi2CallbackFunctions()

        def log2(env, instance, status, category, message):
            logs.append(message.decode())
        cb.logger = fmi2CallbackLoggerTYPE(log2)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        with pytest.raises(Exception, match="instantiate"):
            fmu.instantiate(callbacks=cb)
    else:
        fmu = FMU3Slave(guid="{not-the-guid}", unzipDirectory=str(unzipdir),
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
        with pytest.raises(Exception, match="instantiate"):
            fmu.instantiate(logMessage=lambda env, status, cat, msg: logs.append(msg.decode()))
    fmu.freeLibrary()
    assert any("does not match" in m for m in logs), logs


@pytest.mark.parametrize("version", [2, 3])
def test_overflowing_input_is_a_step_error_not_a_crash(opened, version):
    s = new_slave(opened, version)
    s.init()
    s.set([CMD], [1e308])  # finite, but the servo acceleration overflows
    s.expect_error(s.step, 0.0, 0.01, contains="not finite")
    s.fmu.reset()
    s.init()
    s.step(0.0, 0.01)
    s.free()


# ----------------------------------------------------------------------------- state, reset, instances


def _drive(s, t0, n, h=0.01, seed=0):
    rng = np.random.default_rng(seed)
    out, t = [], t0
    for _ in range(n):
        s.set([CMD, LOAD], [float(rng.uniform(-0.3, 0.2)), float(rng.normal(0, 5))])
        s.step(t, h)
        t += h
        out.append(s.get([POS, VEL, ACC]))
    return np.array(out), t


@pytest.mark.parametrize("version", [2, 3])
def test_get_set_and_serialize_state_round_trip(opened, version):
    s = new_slave(opened, version)
    s.init(initial_position=-0.1)
    _, t = _drive(s, 0.0, 20, seed=1)
    at_save = s.get([POS, VEL, ACC, CMD, LOAD])
    state = s.fmu.getFMUState()
    blob = s.fmu.serializeFMUState(state)
    first, _ = _drive(s, t, 30, seed=2)

    s.fmu.setFMUState(state)  # restore: same outputs, and the same inputs give identical outputs
    assert s.get([POS, VEL, ACC, CMD, LOAD]) == at_save
    again, _ = _drive(s, t, 30, seed=2)
    np.testing.assert_array_equal(again, first)

    restored = s.fmu.deserializeFMUState(blob)  # deserialized copy behaves the same
    s.fmu.setFMUState(restored)
    third, _ = _drive(s, t, 30, seed=2)
    np.testing.assert_array_equal(third, first)

    # the state carries the mode and parameters: restore after terminate, into a fresh instance
    s.fmu.terminate()
    s.fmu.setFMUState(state)
    fourth, _ = _drive(s, t, 30, seed=2)
    np.testing.assert_array_equal(fourth, first)
    s.fmu.freeFMUState(state)
    s.fmu.freeFMUState(restored)

    other = new_slave(opened, version, "other")
    st = other.fmu.deserializeFMUState(blob)
    other.fmu.setFMUState(st)
    assert other.get([PARAM["initial_position"]]) == [-0.1]
    fifth, _ = _drive(other, t, 30, seed=2)
    np.testing.assert_array_equal(fifth, first)
    other.fmu.freeFMUState(st)

    # garbage is rejected with a message
    bad = bytearray(blob)
    bad[:8] = b"garbage!"
    other.expect_error(other.fmu.deserializeFMUState, bytes(bad), contains="not an FMU state")
    other.expect_error(other.fmu.deserializeFMUState, blob[:-8], contains="bytes given")
    other.free()
    s.free()


def _state_fields(blob):
    """Byte offsets of the fields of a serialized state of the wrapper (cs_core.h FmuState):
    header (8-byte tag, 6 uint32, uint64 GUID hash), then x, u, p, time, mode, x_ready."""
    nx, nu, np_ = (int.from_bytes(blob[o:o + 4], "little") for o in (12, 16, 20))
    x0 = 40
    u0 = x0 + 8 * max(nx, 1)
    p0 = u0 + 8 * max(nu, 1)
    t0 = p0 + 8 * max(np_, 1)
    return {"x": x0, "u": u0, "p": p0, "time": t0, "mode": t0 + 8, "x_ready": t0 + 12}


@pytest.mark.parametrize("version", [2, 3])
def test_deserialized_state_is_checked_completely(opened, version):
    """A serialized state is data from outside (a file): a mode that is not one of the
    instance's modes (e.g. instantiated|step, under which a fixed parameter could be set
    while stepping), a bad flag, or a non-finite time, state, input or parameter is refused
    with a message; the instance keeps its own state."""
    import struct

    s = new_slave(opened, version)
    s.init()
    _drive(s, 0.0, 5, seed=3)
    before = s.get([POS, VEL, ACC, CMD, LOAD])
    blob = s.fmu.serializeFMUState(s.fmu.getFMUState())
    off = _state_fields(blob)
    nan = struct.pack("<d", float("nan"))
    cases = [
        ("mode", struct.pack("<i", 1 | 4), "invalid mode 5"),
        ("mode", struct.pack("<i", 3), "invalid mode 3"),
        ("mode", struct.pack("<i", 0), "invalid mode 0"),
        ("x_ready", struct.pack("<i", 7), "initial-state flag 7"),
        ("x_ready", struct.pack("<i", 0), "without an initialized system state"),
        ("time", nan, "time nan is not finite"),
        ("x", nan, "x[0] = nan is not finite"),
        ("u", struct.pack("<d", float("inf")), "input 'command' = inf"),
        ("p", nan, "parameter '"),
    ]
    for field, value, message in cases:
        bad = bytearray(blob)
        bad[off[field]:off[field] + len(value)] = value
        s.expect_error(s.fmu.deserializeFMUState, bytes(bad), contains=message)
    assert s.get([POS, VEL, ACC, CMD, LOAD]) == before
    st = s.fmu.deserializeFMUState(blob)  # the untouched state still loads
    s.fmu.setFMUState(st)
    s.fmu.freeFMUState(st)
    s.free()


@pytest.mark.parametrize("version", [2, 3])
def test_one_do_step_is_bounded_by_the_declared_maximum_step(opened, version, fmus):
    """doStep longer than the declared maximum communication step (MAX_STEPS internal steps,
    stated in the model description) is an error at once, not hours of computation."""
    from lpvpc.export.fmu_build import MAX_STEPS

    md, _ = opened[version]
    step = float(md.defaultExperiment.stepSize)
    assert f"at most {MAX_STEPS * step!r} s" in md.description
    s = new_slave(opened, version)
    s.init()
    s.expect_error(s.step, 0.0, (MAX_STEPS + 1) * step, contains="maximum communication step")
    s.free()
    s = new_slave(opened, version)
    s.init()
    s.expect_error(s.step, 0.0, 1e9, contains="maximum communication step")
    s.free()
    s = new_slave(opened, version)
    s.init()
    s.step(0.0, MAX_STEPS * step)  # the maximum itself is allowed
    assert all(math.isfinite(v) for v in s.get([POS, VEL, ACC]))
    s.free()


@pytest.mark.parametrize("version", [2, 3])
def test_reset_gives_the_same_run_again(opened, version):
    s = new_slave(opened, version)
    s.init(servo_bandwidth=25.0)
    a, _ = _drive(s, 0.0, 50, seed=3)
    s.fmu.terminate()
    s.fmu.reset()
    s.init(servo_bandwidth=25.0)
    b, _ = _drive(s, 0.0, 50, seed=3)
    np.testing.assert_array_equal(a, b)
    s.fmu.reset()  # reset restores the default parameters
    s.init()
    assert s.get([PARAM["servo_bandwidth"]]) == [ACTUATOR_DEFAULTS["servo_bandwidth"]]
    s.free()


@pytest.mark.parametrize("version", [2, 3])
def test_two_instances_at_once_are_independent(opened, version):
    solo = {}
    for seed in (4, 5):
        s = new_slave(opened, version, f"solo{seed}")
        s.init(initial_position=0.01 * seed)
        solo[seed], _ = _drive(s, 0.0, 40, seed=seed)
        s.free()
    a, b = new_slave(opened, version, "a"), new_slave(opened, version, "b")
    a.init(initial_position=0.04)
    b.init(initial_position=0.05, servo_stiffness=ACTUATOR_DEFAULTS["servo_stiffness"])
    ra, rb, t = [], [], 0.0
    rng_a, rng_b = np.random.default_rng(4), np.random.default_rng(5)
    for _ in range(40):  # interleaved
        for s, rng, rec in ((a, rng_a, ra), (b, rng_b, rb)):
            s.set([CMD, LOAD], [float(rng.uniform(-0.3, 0.2)), float(rng.normal(0, 5))])
            s.step(t, 0.01)
            rec.append(s.get([POS, VEL, ACC]))
        t += 0.01
    np.testing.assert_array_equal(np.array(ra), solo[4])
    np.testing.assert_array_equal(np.array(rb), solo[5])
    a.free()
    b.free()


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="needs /proc (Linux)")
@pytest.mark.parametrize("version", [2, 3])
def test_instantiate_reset_free_cycles_have_bounded_memory(opened, version):
    """200 cycles here; benchmarks/bench_fmu_cycles.py runs 2000 and records the result."""
    md, unzipdir = opened[version]
    base = Slave(unzipdir, md, "keeper")  # keeps the library loaded

    def cycle(k):
        s = Slave(unzipdir, md, f"c{k}")
        s.init()
        s.set([CMD], [0.1])
        s.step(0.0, 0.01)
        st = s.fmu.getFMUState()
        blob = s.fmu.serializeFMUState(st)
        st2 = s.fmu.deserializeFMUState(blob)
        s.fmu.freeFMUState(st)
        s.fmu.freeFMUState(st2)
        s.fmu.reset()
        s.init()
        s.step(0.0, 0.01)
        s.fmu.terminate()
        (s.fmu.fmi2FreeInstance if version == 2 else s.fmu.fmi3FreeInstance)(s.fmu.component)
        s.fmu.freeLibrary()  # drops this handle's reference; `base` keeps the library loaded

    for k in range(30):  # warm up allocator and caches
        cycle(k)
    before = _rss_bytes()
    for k in range(200):
        cycle(k)
    growth = _rss_bytes() - before
    assert growth < 5 * 2**20, f"RSS grew by {growth / 2**20:.2f} MB over 200 cycles"
    base.free()


def test_fmpy_compile_passes_the_preprocessor_definitions_of_fmi3(tiny, tmp_path):
    if shutil.which("cmake") is None:
        pytest.skip("cmake (needed by fmpy compile) not installed")
    from fmpy.build import build_platform_binary

    md, unzipdir = tiny[3]
    d = (tmp_path / "x").resolve()
    shutil.copytree(unzipdir, d)
    shutil.rmtree(d / "binaries")
    (tmp_path / "cmake").mkdir()
    build_platform_binary(d, build_dir=tmp_path / "cmake")  # tiny.c has #error without TINY_GAIN
    s = Slave(d, read_model_description(str(d)))
    s.init()
    s.set([3], [-50.0])
    s.step(0.0, 0.01)
    assert s.get([1]) == [0.5]
    s.free()
