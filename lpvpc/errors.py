"""Exceptions of lpvpc.

The library never prints or exits; it raises one of these. The command line turns
them into one line and an exit status (2 for bad input, 1 for other failures).
"""

from __future__ import annotations


class LpvpcError(Exception):
    """Base class of every error lpvpc raises on purpose.

    Catch every error lpvpc raises on purpose with this class; ``exit_status`` is what the
    command line exits with (2: bad input):

    >>> from lpvpc.io import PerturbationData
    >>> try:
    ...     PerturbationData(position=[0.0, float("nan")], torque=[0.0, 1.0], scheduling=[0.0, 0.0], fs=100.0)
    ... except LpvpcError as exc:
    ...     print(type(exc).__name__, exc.exit_status)
    DataError 2
    """

    exit_status = 1


class DataError(LpvpcError, ValueError):
    """Input data are unusable.

    ``problems`` lists every problem found (each names the channel, index and count),
    so that a user fixes a file once rather than once per problem.

    >>> err = DataError(["channel 'torque': 3 NaN values, first at index 7", "time is not increasing"], "PT.csv")
    >>> str(err)
    "PT.csv: channel 'torque': 3 NaN values, first at index 7; time is not increasing"
    >>> len(err.problems), isinstance(err, ValueError)
    (2, True)
    """

    exit_status = 2

    def __init__(self, problems, source: str | None = None):
        if isinstance(problems, str):
            problems = [problems]
        self.problems = list(problems)
        self.source = source
        prefix = f"{source}: " if source else ""
        super().__init__(prefix + "; ".join(self.problems))


def non_finite_problem(channel: str, x) -> str | None:
    """The :class:`DataError` problem for the NaN and inf values of one channel, naming the
    count and the first index, or None when every value is finite.

    >>> import numpy as np
    >>> non_finite_problem("torque", np.array([0.0, 1.0, np.nan, np.inf]))
    'channel torque: 2 non-finite values, first at index 2'
    >>> non_finite_problem("torque", np.zeros(3)) is None
    True
    """
    import numpy as np

    bad = ~np.isfinite(np.asarray(x, dtype=float))
    if not bad.any():
        return None
    return f"channel {channel}: {int(bad.sum())} non-finite values, first at index {int(np.argmax(bad))}"


class InsufficientExcitationError(LpvpcError, ValueError):
    """The data cannot determine the requested parameters (too few samples, no
    perturbation, rank-deficient regressor).

    >>> issubclass(InsufficientExcitationError, LpvpcError), InsufficientExcitationError.exit_status
    (True, 2)
    """

    exit_status = 2


class IdentificationError(LpvpcError, RuntimeError):
    """The identification algorithm failed on data that passed the input checks.

    >>> issubclass(IdentificationError, RuntimeError), IdentificationError.exit_status
    (True, 1)
    """


class ModelFileError(LpvpcError, ValueError):
    """A saved model file is missing, corrupt or of an unknown format version.

    >>> from lpvpc.models.model import LPVPCModel
    >>> LPVPCModel.from_dict({"format": "something else"})
    Traceback (most recent call last):
    ...
    lpvpc.errors.ModelFileError: model: not an lpvpc model file (missing 'format': 'lpvpc-model')
    """

    exit_status = 2


class ExportError(LpvpcError, RuntimeError):
    """Code generation, compilation or packaging of an export failed.

    >>> from lpvpc.export.fmu_build import FmuVariable, build_fmu
    >>> build_fmu("x.fmu", model_identifier="1bad", system_sources=[], nx=1, step_size=0.01,
    ...           outputs=[FmuVariable("torque", "output", "N.m")], inputs=[], parameters=[])
    Traceback (most recent call last):
    ...
    lpvpc.errors.ExportError: cannot build FMU: model_identifier '1bad' is not a C identifier; system_sources is empty
    """



class StepSizeError(LpvpcError, ValueError):
    """A host asked an exported step function to advance by a time step that is not its tick
    (a fixed-step model run at another step would run its model time at another speed).

    >>> from lpvpc.export.exporter import CasadiExport
    >>> CasadiExport(None, {"tick_s": 0.001}).check_step(0.0005)
    Traceback (most recent call last):
    ...
    lpvpc.errors.StepSizeError: time step 0.0005 s is not the exported function's tick 0.001 s: call it once per tick (step your host at 0.001 s, or call the function every 0.001 s of host time)
    """

    exit_status = 2

class FMUError(LpvpcError, RuntimeError):
    """An FMU is missing, corrupt, built for another platform, or returned an error.

    >>> from lpvpc.validation.fmu import inspect_fmu
    >>> inspect_fmu("no_such.fmu")
    Traceback (most recent call last):
    ...
    lpvpc.errors.FMUError: ...file not found...
    """

    exit_status = 2


class LpvpcWarning(UserWarning):
    """Base class of the warnings lpvpc issues on purpose (the CLI prints each as one line).

    >>> import warnings
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore", LpvpcWarning)  # silence all of lpvpc's warnings
    ...     warnings.warn("outside the identified range", OutOfRangeWarning)
    """


class OutOfRangeWarning(LpvpcWarning):
    """Scheduling or velocity values lie outside the range the model was identified on.

    >>> issubclass(OutOfRangeWarning, LpvpcWarning)
    True
    """


class UnitWarning(LpvpcWarning):
    """Values look like they are in other units than the ones declared (e.g. degrees).

    >>> import tempfile, warnings
    >>> import numpy as np
    >>> from lpvpc.io import Trial, load_trial, write_trial_csv
    >>> t = np.arange(500) / 100.0
    >>> with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     write_trial_csv(Trial(t, 20.0 * np.sin(t), np.zeros(500)), f"{tmp}/PT.csv")  # degrees
    ...     _ = load_trial(f"{tmp}/PT.csv")  # read as rad (the default position_unit)
    >>> [type(w.message).__name__ for w in caught]
    ['UnitWarning']
    """


class PhysiologyWarning(LpvpcWarning):
    """An identified model is physiologically implausible (e.g. negative elastic stiffness
    over most of the range: usually a reversed torque sign convention).

    >>> issubclass(PhysiologyWarning, LpvpcWarning)  # see lpvpc.identification.identify.check_physiology
    True
    """


class StationaryWarning(LpvpcWarning):
    """The scheduling variable does not vary: a position-independent (LTI) parallel cascade
    was identified instead of the LPV model.

    >>> issubclass(StationaryWarning, LpvpcWarning)
    True
    """
