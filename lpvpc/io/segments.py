"""Segments: several trials in one identification record, with nothing crossing the seams.

A lab records several PT/UT pairs per subject; :func:`lpvpc.io.join_trials` puts them
end to end in one :class:`~lpvpc.io.PerturbationData` whose ``segments`` say where each
trial starts and stops. Every regressor that looks at neighbouring samples is built trial
by trial, each trial treated as a record of its own under the model's record-edge rule
(:mod:`lpvpc.models.equations`: zero before a record, the last value held after it), then stacked:
IRF lags, central-difference velocities and accelerations, the reflex delay, the reflex
dynamics' filters (each trial starts from rest) and the MOESP block Hankel matrices (whose
columns that would span two trials are left out). The joint least-squares problem is then
the sum of the trials' problems: a trial adds rows, never a seam.
"""

from __future__ import annotations

import numpy as np


class Segments:
    """Half-open sample ranges ``[(start, stop), ...]`` that tile ``0..n`` in order.

    >>> s = Segments([(0, 3), (3, 5)], 5)  # two trials of 3 and 2 samples
    >>> len(s), s.lengths
    (2, [3, 2])
    >>> s.map(np.cumsum, np.ones(5))  # each trial on its own, then stacked
    array([1., 2., 3., 1., 2.])
    """

    def __init__(self, bounds, n: int):
        bounds = [(int(a), int(b)) for a, b in bounds] or [(0, int(n))]
        edges = [a for a, _ in bounds] + [bounds[-1][1]]
        if edges[0] != 0 or edges[-1] != n or any(a >= b for a, b in bounds) or any(
                bounds[i][1] != bounds[i + 1][0] for i in range(len(bounds) - 1)):
            raise ValueError(f"segments {bounds} do not tile 0..{n} in order")
        self.bounds = bounds

    @classmethod
    def of(cls, data, n: int) -> "Segments":
        """The segments of ``data`` (its ``segments`` attribute; one segment if it has none)."""
        return cls(getattr(data, "segments", ()) or (), n)

    def __len__(self) -> int:
        return len(self.bounds)

    def __iter__(self):
        return iter(self.bounds)

    @property
    def lengths(self) -> list[int]:
        return [b - a for a, b in self.bounds]

    def map(self, func, *arrays, **kwargs):
        """``func`` applied to each segment of ``arrays`` (sliced along axis 0), the results
        stacked along axis 0; one segment calls ``func`` on the whole arrays."""
        if len(self.bounds) == 1:
            return func(*arrays, **kwargs)
        return np.concatenate([func(*(x[a:b] for x in arrays), **kwargs) for a, b in self.bounds], axis=0)
