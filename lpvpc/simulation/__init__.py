"""The virtual subject: a physics-based ankle on a position servo, its trajectories and
perturbation designs, the effects the base model lacks, EMG, and a compliant loop.

The main entry points are re-exported here; the modules are
:mod:`~lpvpc.simulation.simulate`, :mod:`~lpvpc.simulation.subject`,
:mod:`~lpvpc.simulation.trajectories`, :mod:`~lpvpc.simulation.simulated_effects`,
:mod:`~lpvpc.simulation.emg`, :mod:`~lpvpc.simulation.physics` and
:mod:`~lpvpc.simulation.compliant_loop`.
"""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "simulate": ["SimulatedPair", "SubjectParams", "simulate_pair", "write_dataset"]})
