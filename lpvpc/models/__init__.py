"""The model: its basis in the scheduling variable, its equations (one definition shared by
numpy, CasADi and the FMU), the fitted LPV parallel-cascade model, its effect terms, its file
format and the intervals read from a stored model.

Modules: :mod:`~lpvpc.models.basis`, :mod:`~lpvpc.models.equations`,
:mod:`~lpvpc.models.intrinsic`, :mod:`~lpvpc.models.reflex`, :mod:`~lpvpc.models.effects`,
:mod:`~lpvpc.models.model`, :mod:`~lpvpc.models.modelfile`, :mod:`~lpvpc.models.uncertainty`.
"""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {"basis": ["Basis"], "model": ["LPVPCModel", "Prediction", "vaf"]})
