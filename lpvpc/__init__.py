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

The package is laid out by concept, each layer importing only the ones before it:

- :mod:`lpvpc.io`: records, files, units and sign conventions, decimation, PT-UT pairing;
- :mod:`lpvpc.models`: the basis, the model equations, the fitted LPV-PC model and its file;
- :mod:`lpvpc.identification`: the estimator and its steps (MOESP, selection, channel skew);
- :mod:`lpvpc.simulation`: the virtual subject;
- :mod:`lpvpc.export`: CasADi functions and FMUs (with their C sources), whole-joint and
  closed-loop models;
- :mod:`lpvpc.diagnosis` and :mod:`lpvpc.validation`: where a model fails, what is missing,
  co-simulation against held-out data;
- :mod:`lpvpc.cli`: the command line.

>>> import lpvpc
>>> lpvpc.LPVPCModel.__name__, callable(lpvpc.identify), "simulate_pair" in dir(lpvpc)
('LPVPCModel', True, True)
"""

import importlib
import importlib.abc
import importlib.util
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
    "load_identification_data": "lpvpc.io",
    "load_trial": "lpvpc.io",
    "pair_trials": "lpvpc.io",
    "join_trials": "lpvpc.io",
    "write_perturbation_csv": "lpvpc.io",
    "hold_out": "lpvpc.io",
    "PerturbationData": "lpvpc.io",
    "Trial": "lpvpc.io",
    # identification and the fitted model
    "LPVPCEstimator": "lpvpc.identification.identify",
    "LPVPCModel": "lpvpc.models.model",
    "Prediction": "lpvpc.models.model",
    "vaf": "lpvpc.models.model",
    "Interval": "lpvpc.models.uncertainty",
    # the virtual subject
    "simulate_pair": "lpvpc.simulation.simulate",
    "write_dataset": "lpvpc.simulation.simulate",
    "SubjectParams": "lpvpc.simulation.simulate",
    # export
    "export_fmu": "lpvpc.export.exporter",
    "export_casadi": "lpvpc.export.exporter",
    "fit_whole_joint": "lpvpc.export.whole_joint",
    "fit_closed_loop": "lpvpc.export.closed_loop",
    "ClosedLoopModel": "lpvpc.export.closed_loop",
    # validation, diagnosis, improvement
    "validate": "lpvpc.validation",
    "ValidationResult": "lpvpc.validation",
    "Diagnosis": "lpvpc.diagnosis.diagnose",
    "Ladder": "lpvpc.diagnosis.improve",
    # plots
    "plot_torque_fit": "lpvpc.plotting",
}
#: modules that are called as their function of the same name: public name -> module
_ENTRY_MODULES = {
    "identify": "lpvpc.identification.identify",
    "diagnose": "lpvpc.diagnosis.diagnose",
    "improve": "lpvpc.diagnosis.improve",
}

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


class _EntryModule(types.ModuleType):
    """A module callable as its function of the same name (``lpvpc.identify(data)``)."""

    def __call__(self, *args, **kwargs):
        return getattr(self, self.__name__.rpartition(".")[2])(*args, **kwargs)


def _entry_module(name):
    """The entry module ``lpvpc.<name>``, made callable as its function of that name."""
    module = importlib.import_module(_ENTRY_MODULES[name])
    if type(module) is types.ModuleType:
        module.__class__ = _EntryModule
    sys.modules.setdefault(f"{__name__}.{name}", module)
    return module


def __getattr__(name):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    if name in _ENTRY_MODULES:
        value = _entry_module(name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    # ``import lpvpc.identify`` binds the entry module to this package's attribute of its name;
    # the module is made callable there, so ``lpvpc.identify`` is the same callable object
    # whichever way it was first reached.
    def __setattr__(self, name, value):
        if name in _ENTRY_MODULES and isinstance(value, types.ModuleType) and type(value) is types.ModuleType:
            value.__class__ = _EntryModule
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


class _EntryModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """``import lpvpc.identify`` (and ``diagnose``, ``improve``) finds the entry module in its
    subpackage: one module object under both names, so attributes set on either are seen by
    both."""

    def find_spec(self, fullname, path=None, target=None):
        package, _, name = fullname.rpartition(".")
        if package == __name__ and name in _ENTRY_MODULES:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        return _entry_module(spec.name.rpartition(".")[2])

    def exec_module(self, module):
        pass  # already executed under its own name


sys.meta_path.append(_EntryModuleFinder())
