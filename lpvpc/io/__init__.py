"""Trials, loaders, checks, decimation and PT-UT pairing: the public names of the data
modules, importable from here as before.

Units: time in s, position in rad, torque in N m, velocity in rad/s, rates in Hz
(SI everywhere). Loaders convert from the lab's units and sign convention on the way in
(``position_unit``, ``torque_sign``); everything after them is SI.

Bad data are never repaired: every check collects all the problems it finds and raises
one :class:`~lpvpc.errors.DataError` that lists them (channel, first index, count).

Where each concept lives:

- :mod:`lpvpc.io.trial`: the :class:`~lpvpc.io.trial.Trial` record and its checks;
- :mod:`lpvpc.io.readers`: CSV and ``.mat`` files read into trials (:func:`~lpvpc.io.readers.load_trial`);
- :mod:`lpvpc.io.conventions`: units and sign to SI, and the mistakes caught on the way in
  (degrees, ms time, PT/UT swap);
- :mod:`lpvpc.io.decimation`: decimation and resampling to the model rate;
- :mod:`lpvpc.io.identification_data`: :class:`~lpvpc.io.identification_data.PerturbationData`,
  PT-UT pairing, stationary trials, perturbation files, joined trials.
"""

from .._lazy import attach

# The public names of the io modules, as ``lpvpc.io.NAME`` (each loaded on first use)
__getattr__, __dir__, __all__ = attach(__name__, {
    "conventions": ["MS_MAX_RATE", "MS_MIN_RATE", "SWAP_RATIO", "SWAP_WINDOW"],
    "decimation": ["FIR_ATTENUATION_DB", "FIR_TAPS_PER_FACTOR", "MAX_STAGE_FACTOR", "decimate_signal",
                   "decimate_trial", "decimation_factor", "multiple_rate", "resample_trial", "to_multiple_rate"],
    "identification_data": ["MIN_PERTURBATION_VARIANCE", "STATIONARY_MAX_SPAN", "STATIONARY_WINDOW", "HighRate",
                            "PerturbationData", "hold_out", "RecordSource", "join_trials", "load_identification_data", "load_perturbation_file",
                            "pair_trials", "perturbation_file_trials", "stationary_perturbation", "stationary_ut",
                            "write_perturbation_csv"],
    "matfiles": ["split_variable"],
    "readers": ["PERTURBATION_EMG", "load_trial"],
    "trial": ["ANGLE_CHANNELS", "GRID_TOLERANCE", "JITTER_TOLERANCE", "OPTIONAL_CHANNELS", "RATE_TOLERANCE",
              "REQUIRED_CHANNELS", "Trial", "check_model_rate", "check_trial", "grid_deviation", "trial_problems", "write_trial_csv"],
})
