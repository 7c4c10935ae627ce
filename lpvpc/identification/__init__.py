"""Identification: the subspace LPV parallel-cascade estimator and its steps.

Modules: :mod:`~lpvpc.identification.identify` (the estimator and :func:`lpvpc.identify <lpvpc.identification.identify.identify>`),
:mod:`~lpvpc.identification.subspace` (MOESP), :mod:`~lpvpc.identification.selection`
(structure selection by cross-validation), :mod:`~lpvpc.identification.structural_uncertainty`,
:mod:`~lpvpc.identification.channel_skew` and :mod:`~lpvpc.identification.skew_scan` (the
measured channels lined up in time).
"""
