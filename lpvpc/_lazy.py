"""Lazy re-exports for the package's ``__init__`` modules.

A subpackage's public names are importable from the subpackage itself (``from lpvpc.io
import load_trial``), but loading them there would import every module of the subpackage,
and with them numpy, scipy.signal and casadi, whenever any one of its modules is imported
(the command line's help must start without them). Each name is therefore loaded from its
module on first access.
"""

import importlib


def attach(package: str, exports: dict):
    """``__getattr__``, ``__dir__`` and ``__all__`` for ``package`` re-exporting ``exports``.

    Parameters
    ----------
    package : str
        The subpackage's ``__name__``.
    exports : dict
        ``{submodule (relative to the package): names}``.

    Returns
    -------
    tuple
        ``(__getattr__, __dir__, __all__)`` to assign in the package's ``__init__``.

    Examples
    --------
    >>> getattr_, dir_, all_ = attach("lpvpc.io", {"trial": ["Trial"]})
    >>> getattr_("Trial").__name__, all_
    ('Trial', ['Trial'])
    """
    where = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name):
        if name in where:
            return getattr(importlib.import_module(f"{package}.{where[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__():
        return sorted(where)

    return __getattr__, __dir__, sorted(where)
