"""Diagnosis: where a model fails on held-out data, which physical effect is missing
(:func:`lpvpc.diagnose`), and the improvement ladder that adds effects one at a time
(:func:`lpvpc.improve`).

Modules: :mod:`~lpvpc.diagnosis.diagnose`, :mod:`~lpvpc.diagnosis.where`,
:mod:`~lpvpc.diagnosis.candidates`, :mod:`~lpvpc.diagnosis.signals`,
:mod:`~lpvpc.diagnosis.surrogate`, :mod:`~lpvpc.diagnosis.cv`,
:mod:`~lpvpc.diagnosis.report` and :mod:`~lpvpc.diagnosis.improve`.
"""
