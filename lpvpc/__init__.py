"""lpvpc: identify how ankle stiffness changes with joint position (LPV parallel-cascade
models, subspace method of Sobhani Tehrani, Jalaleddini and Kearney, EMBC 2014) and
export the identified model as a CasADi function and an FMU.

The names a user needs are importable from here::

    from lpvpc import load_identification_data, LPVPCEstimator, identify, LPVPCModel
    data = load_identification_data(pt="PT.csv", ut="UT.csv")     # SI units, 100 Hz
    model = LPVPCEstimator().fit(data).model_  # or identify(data)
    model.export_fmu("ankle.fmu")

``import lpvpc`` stays cheap: each name loads its module on first use (``__getattr__``).
``identify``, ``diagnose`` and ``improve`` are modules of the same name as their main
function; they can be called as that function (``lpvpc.identify(data)``) and still give
their other names as attributes (``lpvpc.diagnose.format_table``).

>>> import lpvpc
>>> lpvpc.LPVPCModel.__name__, callable(lpvpc.identify), "simulate_pair" in dir(lpvpc)
('LPVPCModel', True, True)
"""

import importlib
import sys
import types

__version__ = "0.1.0"

from .errors import (  # noqa: E402
    DataError,
    ExportError,
    FMUError,
    IdentificationError,
    InsufficientExcitationError,
    LpvpcError,
    LpvpcWarning,
    ModelFileError,
    OutOfRangeWarning,
    PhysiologyWarning,
    UnitWarning,
)

#: public name -> module that defines it (loaded on first access)
_LAZY = {
    # data: loaders and the objects they return
    "load_identification_data": "lpvpc.data",
    "load_trial": "lpvpc.data",
    "pair_trials": "lpvpc.data",
    "join_trials": "lpvpc.data",
    "write_perturbation_csv": "lpvpc.data",
    "PerturbationData": "lpvpc.data",
    "Trial": "lpvpc.data",
    # identification and the fitted model
    "LPVPCEstimator": "lpvpc.identify",
    "LPVPCModel": "lpvpc.model",
    "Prediction": "lpvpc.model",
    "vaf": "lpvpc.model",
    "Interval": "lpvpc.uncertainty",
    # the virtual subject
    "simulate_pair": "lpvpc.simulate",
    "write_dataset": "lpvpc.simulate",
    "SubjectParams": "lpvpc.simulate",
    # export
    "export_fmu": "lpvpc.export",
    "export_casadi": "lpvpc.export",
    "fit_whole_joint": "lpvpc.whole_joint",
    "fit_closed_loop": "lpvpc.closed_loop",
    "ClosedLoopModel": "lpvpc.closed_loop",
    # validation, diagnosis, improvement
    "validate": "lpvpc.validation",
    "ValidationResult": "lpvpc.validation",
    "Diagnosis": "lpvpc.diagnose",
    "Ladder": "lpvpc.improve",
    # plots
    "plot_torque_fit": "lpvpc.plotting",
}
#: modules that are called as their function of the same name
_ENTRY_MODULES = ("identify", "diagnose", "improve")

__all__ = [
    "__version__",
    "DataError",
    "ExportError",
    "FMUError",
    "IdentificationError",
    "InsufficientExcitationError",
    "LpvpcError",
    "LpvpcWarning",
    "ModelFileError",
    "OutOfRangeWarning",
    "PhysiologyWarning",
    "UnitWarning",
    *_LAZY,
    *_ENTRY_MODULES,
]


def __getattr__(name):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    if name in _ENTRY_MODULES:
        return importlib.import_module(f"{__name__}.{name}")  # bound by the import (see _Package)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _EntryModule(types.ModuleType):
    """A module callable as its function of the same name (``lpvpc.identify(data)``)."""

    def __call__(self, *args, **kwargs):
        return getattr(self, self.__name__.rpartition(".")[2])(*args, **kwargs)


class _Package(types.ModuleType):
    # The import system binds a submodule to the package's attribute of its name, whoever
    # imports it first; making the module callable there means ``from lpvpc import identify``
    # gives the same object whatever was imported before (the function would lose to the
    # module otherwise).
    def __setattr__(self, name, value):
        if name in _ENTRY_MODULES and isinstance(value, types.ModuleType) and type(value) is types.ModuleType:
            value.__class__ = _EntryModule
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
