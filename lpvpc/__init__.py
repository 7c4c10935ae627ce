"""lpvpc: identify how ankle stiffness changes with joint position (LPV parallel-cascade
models, subspace method of Sobhani Tehrani, Jalaleddini and Kearney, EMBC 2014) and
export the identified model as a CasADi function and an FMU."""

__version__ = "0.1.0"

from .errors import (  # noqa: E402
    DataError,
    ExportError,
    FMUError,
    IdentificationError,
    InsufficientExcitationError,
    LpvpcError,
    ModelFileError,
    OutOfRangeWarning,
    UnitWarning,
)

__all__ = [
    "__version__",
    "DataError",
    "ExportError",
    "FMUError",
    "IdentificationError",
    "InsufficientExcitationError",
    "LpvpcError",
    "ModelFileError",
    "OutOfRangeWarning",
    "UnitWarning",
]
