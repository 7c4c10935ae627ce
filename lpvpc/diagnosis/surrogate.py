"""The surrogate: the model's structure on a record as blocks of a linear least-squares
problem, which the candidates and the signal probes add to or replace.

With the structure held (IRF lags, bases and ranges, reflex delay and linear dynamics) the
torque is linear in the intrinsic IRF coefficients, the reflex nonlinearity's coefficients
(filtered by the model's reflex dynamics), the numerator of those dynamics and the model's
effects: :class:`Surrogate` builds those blocks in a :class:`~lpvpc.diagnosis.cv.BlockCV`
("refit" design) or holds the model and fits its residual ("fixed" design).
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from ..models import equations as eq
from ..models.basis import Basis
from .cv import BLOCK_S, FIXED_RIDGE, FOLDS, BlockCV
from ..models.effects import EffectDesign, reflex_latency, signals_from_data
from ..models.reflex import reflex_input_regressor


class Surrogate:
    """The model's structure on a record as blocks of a linear least-squares problem.

    Base blocks: ``intrinsic`` (the IRF, model lags and basis), ``effects`` (the model's
    own effect terms, if any) and ``reflex`` (:meth:`reflex_block` at the model's delay).
    """

    def __init__(self, model, data, folds=FOLDS, *, design="refit", mask=None, prediction=None):
        """``design``: "refit" (the model's structure refitted with every candidate) or
        "fixed" (the model held as it is: candidates are fitted to its residual, which
        holds on records too short or narrow to refit the whole structure; settings
        candidates then add their columns instead of replacing the model's).
        ``mask``: samples left out (e.g. outside the identified range); ``prediction``:
        the model's torque on the data (needed by the fixed design)."""
        self.model = model
        self.data = data
        self.design = design
        self.p = np.asarray(data.position, dtype=float)
        self.rho = np.asarray(data.scheduling, dtype=float)
        self.fs = float(data.fs)
        self.signals = signals_from_data(data)
        self.L = -min(model.lags)
        self.z = None
        y = np.asarray(data.torque, dtype=float)
        yin = y if mask is None else y[np.asarray(mask, dtype=bool)]
        self.sst = float(np.sum((yin - yin.mean()) ** 2))  # of the measured torque: VAF gains are relative to it
        if design == "fixed":
            self.cv = BlockCV(y - prediction, folds, mask, interleave=int(round(BLOCK_S * self.fs)))
            self.cv.ridge = FIXED_RIDGE
            self.base = []
            return
        self.cv = BlockCV(y, folds, mask)
        self.base = ["intrinsic", "reflex"]
        self.cv.add("intrinsic", self.intrinsic_block(model.lags, model.intrinsic_basis))
        self.cv.add("reflex", self.reflex_block(model.delay, model.velocity_basis, model.reflex_rho_basis))
        names = [fe.name for fe in model.effects]
        if names:
            design = EffectDesign(names, self.p, self.rho, self.fs, model.lags, model.intrinsic_basis, self.signals,
                                  source=data.source or "data")
            X_r, _ = design.reflex_columns(model)
            self.cv.add("effects", np.hstack([design.columns, X_r]))
            self.base.insert(1, "effects")

    def with_change(self, blocks, repl):
        """Blocks after a settings change ``repl`` ({base block: replacement}): replaced in
        the refit design, added in the fixed one."""
        if self.design == "fixed":
            return list(blocks) + [v for v in repl.values() if v not in blocks]
        return [repl.get(b, b) for b in blocks]

    def intrinsic_block(self, lags, basis: Basis):
        return eq.kron_rows(eq.lagged(self.p, lags), basis.evaluate(self.rho))

    def reflex_block(self, delay, velocity_basis: Basis, rho_basis: Basis):
        """Reflex columns at ``delay`` (samples): every basis function of the nonlinearity
        (eq. 17) through the model's reflex dynamics C (zI - A)^-1 B + D, and the model's
        own nonlinearity at that delay through each state and the feedthrough (a free,
        position-independent numerator)."""
        m = self.model
        dvel = eq.delayed_velocity(self.p, self.fs, delay)
        U = reflex_input_regressor(velocity_basis.evaluate(dvel), rho_basis.evaluate(self.rho))
        num, den = scipy.signal.ss2tf(m.A, m.B[:, None], m.C[None, :], np.array([[m.D]]))
        z = m.reflex_drive(self.p, self.rho, delay=delay)
        return np.hstack([scipy.signal.lfilter(num[0], den, U, axis=0), eq.state_trajectory(m.A, m.B, z), z[:, None]])

    def interleaved(self):
        """(BlockCV, held-out base residual) of the same base on interleaved folds (2-s
        blocks dealt to the folds in turn; the fixed design's own folds already are): a
        held-out block then lies between training blocks, which a slowly varying function
        of trial time needs."""
        if self.cv.parts and not isinstance(self.cv.parts[0], slice):
            return self.cv, self.cv.fit(self.base)[0]
        if not hasattr(self, "_interleaved"):
            w = None if self.cv.w is None else self.cv.w > 0
            cv = BlockCV(np.asarray(self.data.torque, dtype=float), self.cv.K, w,
                         interleave=int(round(BLOCK_S * self.fs)))
            cv.ridge = self.cv.ridge
            for b in self.base:
                cv.add(b, self.cv.blocks[b])
            self._interleaved = (cv, cv.fit(self.base)[0])
        return self._interleaved

    def emg_latency(self):
        """:func:`lpvpc.models.effects.reflex_latency` of the perturbed trial's EMG against the
        model's reflex nonlinearity on the undelayed velocity (None without EMG)."""
        if not hasattr(self, "_emg_latency"):
            self._emg_latency = None
            if "emg" in self.signals:
                z = self.model.reflex_drive(self.p, self.rho, delay=0)  # the undelayed velocity
                mask = None if self.cv.w is None else self.cv.w > 0
                self._emg_latency = reflex_latency(self.signals["emg"], z, self.rho, self.fs, mask=mask)
        return self._emg_latency

    def reflex_drive(self):
        if self.z is None:
            self.z = self.model.reflex_drive(self.p, self.rho)
        return self.z


