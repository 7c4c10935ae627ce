"""Trials, loaders, checks, decimation and PT-UT pairing: the public names of the data
modules, importable from here as before.

Units: time in s, position in rad, torque in N m, velocity in rad/s, rates in Hz
(SI everywhere). Loaders convert from the lab's units and sign convention on the way in
(``position_unit``, ``torque_sign``); everything after them is SI.

Bad data are never repaired: every check collects all the problems it finds and raises
one :class:`~lpvpc.errors.DataError` that lists them (channel, first index, count).

Where each concept lives:

- :mod:`lpvpc.trial`: the :class:`~lpvpc.trial.Trial` record and its checks;
- :mod:`lpvpc.readers`: CSV and ``.mat`` files read into trials (:func:`~lpvpc.readers.load_trial`);
- :mod:`lpvpc.conventions`: units and sign to SI, and the mistakes caught on the way in
  (degrees, ms time, PT/UT swap);
- :mod:`lpvpc.decimation`: decimation and resampling to the model rate;
- :mod:`lpvpc.identification_data`: :class:`~lpvpc.identification_data.PerturbationData`,
  PT-UT pairing, stationary trials, perturbation files, joined trials.
"""

# Re-exports (the public names of the data modules, as ``lpvpc.data.NAME``)
from .conventions import MS_MAX_RATE, MS_MIN_RATE, SWAP_RATIO, SWAP_WINDOW
from .decimation import (FIR_ATTENUATION_DB, FIR_TAPS_PER_FACTOR, MAX_STAGE_FACTOR, decimate_signal,
    decimate_trial, decimation_factor, multiple_rate, resample_trial, to_multiple_rate)
from .identification_data import (MIN_PERTURBATION_VARIANCE, STATIONARY_MAX_SPAN, STATIONARY_WINDOW,
    HighRate, PerturbationData, join_trials, load_identification_data, load_perturbation_file, pair_trials,
    perturbation_file_trials, stationary_perturbation, stationary_ut, write_perturbation_csv)
from .matfiles import split_variable
from .readers import PERTURBATION_EMG, load_trial
from .trial import (ANGLE_CHANNELS, GRID_TOLERANCE, JITTER_TOLERANCE, OPTIONAL_CHANNELS, RATE_TOLERANCE,
    REQUIRED_CHANNELS, Trial, check_model_rate, check_trial, grid_deviation, trial_problems, write_trial_csv)
