"""What the export and FMU tests share: the numpy prediction an exported variant must
reproduce, its comparison after the variant's latency, and an instance of an extracted FMU
(co-simulation or Model Exchange, FMI 2.0 or 3.0) that records what the FMU logs.

The instance calls fmpy directly (no error translation, unlike lpvpc.validation.fmu), so
the tests see the raw status of wrong calls."""

import numpy as np
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Model, FMU2Slave, defaultCallbacks, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.fmi3 import FMU3Model, FMU3Slave


def reference(model, position, scheduling, variant, **kwargs):
    """The numpy prediction (N m) an exported ``variant`` delivers, before its latency:
    {"torque", "torque_intrinsic", "torque_reflex"}; the sampled and causal variants use the
    causal intrinsic IRF, the exact variant the two-sided one."""
    p = model.predict(position, scheduling, causal=variant != "exact", warn=False, **kwargs)
    return {"torque": p.total, "torque_intrinsic": p.intrinsic, "torque_reflex": p.reflex}


def shifted_error(y, ref, latency, scale):
    """max |y[k] - ref[k - latency]| over k >= latency (axis 0), divided by ``scale``."""
    y, ref = np.asarray(y), np.asarray(ref)
    return float(np.max(np.abs(y[latency:] - ref[: len(ref) - latency])) / scale)


def delayed(x, latency):
    """``x`` as a model with ``latency`` samples delivers it: sample k holds x[k - latency], 0 before."""
    x = np.asarray(x)
    return np.concatenate([np.zeros(latency), x[: len(x) - latency]])


_CLASSES = {(2, "cs"): FMU2Slave, (3, "cs"): FMU3Slave, (2, "me"): FMU2Model, (3, "me"): FMU3Model}


class FMUInstance:
    """An instantiated FMU (``interface`` "cs" or "me") from its extracted folder; ``log``
    collects (status, message) of every message; ``set``/``get`` are the float setters and
    getters of its FMI version, ``vr`` maps variable names to value references."""

    def __init__(self, path, unzipdir, name, interface):
        self.md = read_model_description(path)
        self.fmi = 2 if self.md.fmiVersion.startswith("2") else 3
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.log = []
        kind = self.md.coSimulation if interface == "cs" else self.md.modelExchange
        self.fmu = _CLASSES[(self.fmi, interface)](guid=self.md.guid, unzipDirectory=str(unzipdir),
                                                   modelIdentifier=kind.modelIdentifier, instanceName=name)
        if self.fmi == 2:
            cb = fmi2CallbackFunctions()
            cb.logger = fmi2CallbackLoggerTYPE(lambda env, n, s, c, m: self.log.append((s, m.decode())))
            cb.allocateMemory = defaultCallbacks.allocateMemory
            cb.freeMemory = defaultCallbacks.freeMemory
            self._cb = cb  # keep alive while the instance lives
            self.fmu.instantiate(callbacks=cb, loggingOn=False)
            self.set, self.get = self.fmu.setReal, self.fmu.getReal
        else:
            self.fmu.instantiate(loggingOn=False, logMessage=lambda env, s, c, m: self.log.append((s, m.decode())))
            self.set, self.get = self.fmu.setFloat64, self.fmu.getFloat64

    def initialize(self, values=None):
        """Initialise at t = 0 s, setting ``values`` {name: value} in initialisation mode."""
        if self.fmi == 2:
            self.fmu.setupExperiment(startTime=0.0)
            self.fmu.enterInitializationMode()
        else:
            self.fmu.enterInitializationMode(startTime=0.0)
        if values:
            self.set(self.refs(list(values)), list(values.values()))
        self.fmu.exitInitializationMode()
        return self

    def refs(self, names):
        return [self.vr[n] for n in names]
