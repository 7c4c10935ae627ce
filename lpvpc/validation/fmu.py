"""One FMU co-simulation instance for the master: checked loading, named variables, the
FMU's own log captured, a fast stepping path, and every failure as an :class:`~lpvpc.errors.FMUError`.

Units: whatever the FMU declares (the lpvpc FMUs are SI: rad, rad/s, rad/s2, N.m, s).

:func:`inspect_fmu` checks a file before anything is extracted or loaded: it exists, it
is a zip with a readable ``modelDescription.xml``, FMI 2.0 or 3.0 co-simulation, and it
has a binary for this platform (an FMU built for another platform is reported with the
platforms it does have). :class:`FMUInstance` extracts it once, instantiates it with a
logger that records every message the FMU sends, and wraps ``fmi2*``/``fmi3*`` calls:
any status above warning raises ``FMUError`` naming the instance, the call, the
simulation time and the FMU's last log messages. Values passed to and read from the FMU
are plain Python floats; the per-step path calls the ctypes functions of the shared
library directly with preallocated buffers (fmpy's convenience wrappers allocate arrays
on every call, which costs more than the actuator's step itself).
"""

from __future__ import annotations

import ctypes
import hashlib
import re
import shutil
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

from lpvpc.errors import FMUError

__all__ = ["FMUInfo", "inspect_fmu", "FMUInstance", "file_sha256", "fmu_model_hash"]

_STATUS = {0: "OK", 1: "warning", 2: "discard", 3: "error", 4: "fatal", 5: "pending"}
_MODEL_HASH = re.compile(r"model sha256 ([0-9a-f]{64})")


def file_sha256(path) -> str:
    """sha256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass
class FMUInfo:
    """What :func:`inspect_fmu` found out about an FMU file."""

    path: Path
    fmi_version: int
    model_identifier: str
    guid: str
    description: str
    step_size: float | None  # DefaultExperiment stepSize (s), None if absent
    variables: dict  # name -> (value reference, causality)
    dependencies: dict  # output name -> list of input names it depends on directly (None: unknown)
    platforms: list
    sha256: str
    model_description: object = field(repr=False, default=None)

    def names(self, causality) -> list:
        return [n for n, (_, c) in self.variables.items() if c == causality]


def fmu_model_hash(info: FMUInfo) -> str | None:
    """The lpvpc model hash an exported model FMU declares in its description (None if absent)."""
    m = _MODEL_HASH.search(info.description or "")
    return m.group(1) if m else None


def inspect_fmu(path, what: str = "FMU") -> FMUInfo:
    """Check an FMU file and read its model description; raise FMUError with one clear line.

    ``what`` names the FMU's role in messages (e.g. "model FMU").
    """
    import fmpy
    from fmpy import read_model_description, supported_platforms

    path = Path(path)
    if not path.is_file():
        raise FMUError(f"{what} {path}: file not found")
    if not zipfile.is_zipfile(path):
        raise FMUError(f"{what} {path}: corrupt FMU (not a zip archive)")
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
            bad = zf.testzip()
        if bad is not None:
            raise FMUError(f"{what} {path}: corrupt FMU (damaged member {bad})")
        if "modelDescription.xml" not in names:
            raise FMUError(f"{what} {path}: corrupt FMU (no modelDescription.xml)")
        md = read_model_description(str(path), validate=False)
    except FMUError:
        raise
    except Exception as exc:  # fmpy raises plain Exceptions and lxml errors for bad XML
        raise FMUError(f"{what} {path}: corrupt FMU ({type(exc).__name__}: {' '.join(str(exc).split())})") from None
    version = str(md.fmiVersion)
    if not (version.startswith("2.") or version.startswith("3.")):
        raise FMUError(f"{what} {path}: FMI {version} is not supported (FMI 2.0 or 3.0 co-simulation)")
    fmi = 2 if version.startswith("2.") else 3
    if md.coSimulation is None:
        raise FMUError(f"{what} {path}: not a co-simulation FMU (model exchange only)")
    platforms = supported_platforms(str(path))
    binaries = [p for p in platforms if p != "c-code"]
    if fmpy.platform not in binaries:
        have = ", ".join(binaries) or "none"
        extra = "; it ships C sources: rebuild it with 'fmpy compile' or export it again" if "c-code" in platforms else ""
        raise FMUError(f"{what} {path}: built for another platform (binaries for: {have}), "
                       f"not for this machine ({fmpy.platform}){extra}")
    variables, dependencies = {}, {}
    by_index = {}
    for i, v in enumerate(md.modelVariables):
        variables[v.name] = (int(v.valueReference), v.causality)
        by_index[i + 1] = v.name
    for unknown in md.outputs:
        deps = getattr(unknown, "dependencies", None)
        name = unknown.variable.name
        dependencies[name] = None if deps is None else [d.name for d in deps]
    step = None
    if md.defaultExperiment is not None and md.defaultExperiment.stepSize is not None:
        step = float(md.defaultExperiment.stepSize)
    return FMUInfo(path=path, fmi_version=fmi, model_identifier=md.coSimulation.modelIdentifier, guid=md.guid,
                   description=md.description or "", step_size=step, variables=variables,
                   dependencies=dependencies, platforms=platforms, sha256=file_sha256(path),
                   model_description=md)


class FMUInstance:
    """A co-simulation instance of a checked FMU (:func:`inspect_fmu`), FMI 2.0 or 3.0.

    ``instance.log`` holds ``(status, category, message)`` of every message the FMU
    logged. Use as a context manager or call ``close()``.
    """

    def __init__(self, info: FMUInfo, name: str, *, logging_on: bool = False):
        from fmpy import extract

        self.info = info
        self.name = name
        self.fmi = info.fmi_version
        self.log: list = []
        self.time = 0.0
        self._unzipdir = tempfile.mkdtemp(prefix=f"lpvpc-{name}-")
        self.slave = None
        self._instantiated = False
        try:
            extract(str(info.path), unzipdir=self._unzipdir)
            kwargs = dict(guid=info.guid, unzipDirectory=self._unzipdir, modelIdentifier=info.model_identifier,
                          instanceName=name)
            if self.fmi == 2:
                from fmpy.fmi2 import FMU2Slave, defaultCallbacks, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE

                self.slave = FMU2Slave(**kwargs)
                cb = fmi2CallbackFunctions()
                cb.logger = fmi2CallbackLoggerTYPE(self._log2)
                cb.allocateMemory = defaultCallbacks.allocateMemory
                cb.freeMemory = defaultCallbacks.freeMemory
                self._callbacks = cb  # keep alive
                self._call("instantiate", lambda: self.slave.instantiate(callbacks=cb, loggingOn=logging_on))
            else:
                from fmpy.fmi3 import FMU3Slave

                self.slave = FMU3Slave(**kwargs)
                self._call("instantiate", lambda: self.slave.instantiate(loggingOn=logging_on, logMessage=self._log3))
            self._instantiated = True
        except BaseException:
            self.close()
            raise
        dll = self.slave.dll
        self._c = self.slave.component
        if self.fmi == 2:
            self._set_raw, self._get_raw, self._step_raw = dll.fmi2SetReal, dll.fmi2GetReal, dll.fmi2DoStep
        else:
            self._set_raw, self._get_raw, self._step_raw = dll.fmi3SetFloat64, dll.fmi3GetFloat64, dll.fmi3DoStep
            self._flags = [ctypes.c_bool() for _ in range(3)]
            self._last = ctypes.c_double()
            self._b3 = [ctypes.byref(b) for b in self._flags] + [ctypes.byref(self._last)]

    # -- logging -------------------------------------------------------------------------
    def _log2(self, env, instance, status, category, message):
        self.log.append((int(status), _text(category), _text(message)))

    def _log3(self, env, status, category, message):
        self.log.append((int(status), _text(category), _text(message)))

    def last_messages(self, n: int = 2) -> str:
        msgs = [m for s, _, m in self.log if s >= 1] or [m for _, _, m in self.log]
        return " | ".join(" ".join(m.split()) for m in msgs[-n:])

    def _fail(self, call: str, status=None) -> FMUError:
        st = f" with status {_STATUS.get(status, status)}" if status is not None else ""
        log = self.last_messages()
        return FMUError(f"{self.name} ({self.info.path.name}): {call} failed{st} at t = {self.time:.6g} s"
                        + (f"; FMU log: {log}" if log else " (the FMU logged nothing)"))

    def _call(self, call: str, fn):
        try:
            return fn()
        except FMUError:
            raise
        except Exception as exc:
            status = getattr(exc, "status", None)
            err = self._fail(call, status)
            if status is None and not self.log:
                err = FMUError(f"{err} ({type(exc).__name__}: {' '.join(str(exc).split())})")
            raise err from None

    # -- set-up --------------------------------------------------------------------------
    def vrs(self, names, causality=None) -> list:
        """Value references of variables by name; FMUError for unknown names."""
        out = []
        for n in names:
            if n not in self.info.variables:
                raise FMUError(f"{self.name} ({self.info.path.name}): no variable named '{n}'")
            vr, c = self.info.variables[n]
            if causality is not None and c != causality:
                raise FMUError(f"{self.name} ({self.info.path.name}): variable '{n}' is {c}, expected {causality}")
            out.append(vr)
        return out

    def initialize(self, start_time: float = 0.0, parameters: dict | None = None) -> None:
        """Enter initialization mode, set ``parameters`` {name: float}, exit it."""
        self.time = float(start_time)
        s = self.slave
        if self.fmi == 2:
            self._call("fmi2SetupExperiment", lambda: s.setupExperiment(startTime=start_time))
            self._call("fmi2EnterInitializationMode", s.enterInitializationMode)
        else:
            self._call("fmi3EnterInitializationMode", lambda: s.enterInitializationMode(startTime=start_time))
        if parameters:
            names = list(parameters)
            self.set(self.vrs(names), [float(parameters[n]) for n in names])
        self._call(f"fmi{self.fmi}ExitInitializationMode", s.exitInitializationMode)

    # -- values and steps ----------------------------------------------------------------
    def port(self, names, causality=None) -> "Port":
        """Preallocated buffers for fast repeated get/set of the variables ``names``."""
        return Port(self, self.vrs(names, causality))

    def set(self, vrs, values) -> None:
        self.port_for(vrs).set(values)

    def get(self, vrs) -> list:
        return self.port_for(vrs).get()

    def port_for(self, vrs) -> "Port":
        return Port(self, list(vrs))

    def do_step(self, t: float, h: float) -> None:
        """One communication step from ``t`` (s) of length ``h`` (s)."""
        self.time = t
        if self.fmi == 2:
            status = self._step_raw(self._c, t, h, 1)
        else:
            status = self._step_raw(self._c, t, h, True, *self._b3)
        if status > 1:
            raise self._fail(f"fmi{self.fmi}DoStep(t = {t:.6g} s, h = {h:.6g} s)", status)
        self.time = t + h

    def get_state(self):
        s = self.slave
        return self._call("get FMU state", s.getFMUstate if self.fmi == 2 else s.getFMUState)

    def set_state(self, state) -> None:
        s = self.slave
        self._call("set FMU state", lambda: (s.setFMUstate if self.fmi == 2 else s.setFMUState)(state))

    def free_state(self, state) -> None:
        s = self.slave
        self._call("free FMU state", lambda: (s.freeFMUstate if self.fmi == 2 else s.freeFMUState)(state))

    # -- tear-down -----------------------------------------------------------------------
    def close(self) -> None:
        s, self.slave = self.slave, None
        if s is not None:
            try:
                if self._instantiated:
                    try:
                        s.terminate()
                    except Exception:
                        pass
                    s.freeInstance()
                else:
                    s.freeLibrary()
            except Exception:
                pass
        shutil.rmtree(self._unzipdir, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class Port:
    """Fast get/set of a fixed list of Float64 variables of one instance."""

    def __init__(self, inst: FMUInstance, vrs):
        self.inst = inst
        self.n = len(vrs)
        self.vrs = list(vrs)
        self._vr = (ctypes.c_uint32 * self.n)(*vrs)
        self._val = (ctypes.c_double * self.n)()

    def set(self, values) -> None:
        inst = self.inst
        self._val[:] = values
        if inst.fmi == 2:
            status = inst._set_raw(inst._c, self._vr, self.n, self._val)
        else:
            status = inst._set_raw(inst._c, self._vr, self.n, self._val, self.n)
        if status > 1:
            raise inst._fail(f"fmi{inst.fmi}Set{'Real' if inst.fmi == 2 else 'Float64'}", status)

    def get(self) -> list:
        inst = self.inst
        if inst.fmi == 2:
            status = inst._get_raw(inst._c, self._vr, self.n, self._val)
        else:
            status = inst._get_raw(inst._c, self._vr, self.n, self._val, self.n)
        if status > 1:
            raise inst._fail(f"fmi{inst.fmi}Get{'Real' if inst.fmi == 2 else 'Float64'}", status)
        return self._val[:]


def _text(x) -> str:
    if x is None:
        return ""
    return x.decode("utf-8", "replace") if isinstance(x, bytes) else str(x)
