"""Run the portable SSP (:func:`lpvpc.validation.ssp.write_portable_ssp`) in co-simulation engines
other teams maintain: libcosim (``libcosimpy``) and ECOS (``ecospy``), loaded as they are.

Each runner loads the archive, steps it at its base step (the ``osp:FixedStepAlgorithm``
annotation; components step at their ``osp:StepSizeHint``, with the parameter set
``lpvpc.validation.ssp.PARAMETER_SET`` applied) and reads ``model.torque`` at every model
sample time t_k = k T, returning those samples (N m). The exact model FMU's torque at t_k is
that of sample k - L: drop the first L samples to align it with the record.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np

from .ssp import OSP_NAMESPACE, PARAMETER_SET, SSD_NAMESPACES

__all__ = ["ENGINES", "available", "run_portable_ssp", "ssp_steps"]

ENGINES = ("libcosim", "ecos")
_MODULES = {"libcosim": "libcosimpy", "ecos": "ecospy"}


def available(engine: str) -> str | None:
    """None if ``engine`` can run here, else why not (the message of the failed import)."""
    import importlib

    try:
        importlib.import_module(_MODULES[engine])
        if engine == "ecos":
            importlib.import_module("ecospy.EcosSimulation")
    except Exception as exc:  # noqa: BLE001 - an engine's shared library may fail to load in many ways
        return f"{_MODULES[engine]} not usable: {type(exc).__name__}: {exc}"
    return None


def ssp_steps(ssp) -> tuple[float, float, float]:
    """(base step, model step, stop time) in s as the archive states them."""
    with zipfile.ZipFile(ssp) as zf:
        root = ET.fromstring(zf.read("SystemStructure.ssd"))
    ns = {**SSD_NAMESPACES, "osp": OSP_NAMESPACE}
    base = float(root.find("ssd:DefaultExperiment//osp:FixedStepAlgorithm", ns).get("baseStepSize"))
    stop = float(root.find("ssd:DefaultExperiment", ns).get("stopTime"))
    model = root.find(".//ssd:Component[@name='model']", ns)
    return base, float(model.find(".//osp:StepSizeHint", ns).get("value")), stop


def run_portable_ssp(ssp, engine: str) -> np.ndarray:
    """``model.torque`` at t_k = k T, k = 0 .. stop/T, from running ``ssp`` in ``engine``."""
    ssp = str(Path(ssp))
    base, step, stop = ssp_steps(ssp)
    per = int(round(step / base))
    n = int(round(stop / step))
    y = np.empty(n + 1)
    if engine == "ecos":
        from ecospy import EcosSimulation

        sim = EcosSimulation(step_size=base, ssp_path=ssp)
        try:
            sim.init(parameter_set=PARAMETER_SET)
            for k in range(n + 1):
                y[k] = sim.get_real("model::torque")
                if k < n:
                    sim.step(per)
            sim.terminate()
        finally:
            sim.free()
    elif engine == "libcosim":
        from libcosimpy.CosimEnums import CosimVariableType  # noqa: F401 - loads the library's enums
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
        from libcosimpy.CosimObserver import CosimObserver

        log_output_level(CosimLogLevel.ERROR)
        ex = CosimExecution.from_ssp_file(ssp)
        idx = ex.slave_index_from_instance_name("model")
        vr = next(v.reference for v in ex.slave_variables(idx) if v.name in (b"torque", "torque"))
        obs = CosimObserver.create_last_value()
        ex.add_observer(obs)
        ex.step(1)  # initializes; the observer then holds the values at t = base
        y[0] = obs.last_real_values(idx, [vr])[0]
        ex.step(per - 1)
        for k in range(1, n + 1):
            y[k] = obs.last_real_values(idx, [vr])[0]
            if k < n:
                ex.step(per)
    else:
        raise ValueError(f"unknown engine {engine!r}; choose one of {ENGINES}")
    if not np.isfinite(y).all():
        raise RuntimeError(f"{engine}: model.torque not finite at sample {int(np.argmax(~np.isfinite(y)))}")
    return y
