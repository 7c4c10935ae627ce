"""Exceptions of lpvpc.

The library never prints or exits; it raises one of these. The command line turns
them into one line and an exit status (2 for bad input, 1 for other failures).
"""

from __future__ import annotations


class LpvpcError(Exception):
    """Base class of every error lpvpc raises on purpose."""

    exit_status = 1


class DataError(LpvpcError, ValueError):
    """Input data are unusable.

    ``problems`` lists every problem found (each names the channel, index and count),
    so that a user fixes a file once rather than once per problem.
    """

    exit_status = 2

    def __init__(self, problems, source: str | None = None):
        if isinstance(problems, str):
            problems = [problems]
        self.problems = list(problems)
        self.source = source
        prefix = f"{source}: " if source else ""
        super().__init__(prefix + "; ".join(self.problems))


class InsufficientExcitationError(LpvpcError, ValueError):
    """The data cannot determine the requested parameters (too few samples, no
    perturbation, rank-deficient regressor)."""

    exit_status = 2


class IdentificationError(LpvpcError, RuntimeError):
    """The identification algorithm failed on data that passed the input checks."""


class ModelFileError(LpvpcError, ValueError):
    """A saved model file is missing, corrupt or of an unknown format version."""

    exit_status = 2


class ExportError(LpvpcError, RuntimeError):
    """Code generation, compilation or packaging of an export failed."""


class FMUError(LpvpcError, RuntimeError):
    """An FMU is missing, corrupt, built for another platform, or returned an error."""

    exit_status = 2


class LpvpcWarning(UserWarning):
    """Base class of the warnings lpvpc issues on purpose (the CLI prints each as one line)."""


class OutOfRangeWarning(LpvpcWarning):
    """Scheduling or velocity values lie outside the range the model was identified on."""


class UnitWarning(LpvpcWarning):
    """Values look like they are in other units than the ones declared (e.g. degrees)."""


class PhysiologyWarning(LpvpcWarning):
    """An identified model is physiologically implausible (e.g. negative elastic stiffness
    over most of the range: usually a reversed torque sign convention)."""


class StationaryWarning(LpvpcWarning):
    """The scheduling variable does not vary: a position-independent (LTI) parallel cascade
    was identified instead of the LPV model."""
