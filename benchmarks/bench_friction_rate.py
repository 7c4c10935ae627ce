"""Friction features at the file's rate or the model's, with and without a position noise floor.

The nonlinear-viscosity entry of the catalog reads tanh((v_slow + v) / s) - tanh(v_slow / s) of
the model-rate (100 Hz) velocities. A friction torque switches sign within a perturbation's
20-50 ms velocity pulse, which the decimation smooths; the same features computed from the
1 kHz position and decimated as the loaders decimate the torque follow it (the path the reflex
takes from 1 kHz files). Measured here, per population draw with friction
(``draw_subject(seed, effect="nonlinear_viscosity")``, 2-minute pairs at 1 kHz):

* how much of the true friction torque (the noise-free held-out pair minus the same subject
  without friction) each set of features explains (R^2 of a least-squares fit);
* the held-out VAF gain of each set as a diagnosis candidate (the base model's structure
  refitted with it on the held-out pair, :class:`lpvpc.diagnosis.surrogate.Surrogate`), beside
  the true friction torque's own gain (the ceiling of any candidate);

with the recorded position noiseless (the population's default) and with white noise of
``--position-noise`` rad RMS in each trial (default 5e-5: the lab's pilot trial's floor), and
the same candidates' gains on clean draws (no friction: a gain there is what a false alarm
would be made of). Then the pilot trial's own 1 kHz position: its noise floor and its
coherence with the torque (sensor noise is incoherent with the torque; motion is not).

Run: OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_friction_rate.py [--position-noise RAD]
Writes benchmarks/results/friction_rate.txt.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import scipy.signal

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

import lpvpc  # noqa: E402
from lpvpc.diagnosis.candidates import score_candidates  # noqa: E402
from lpvpc.diagnosis.cv import robust_paired_test  # noqa: E402
from lpvpc.diagnosis.surrogate import Surrogate  # noqa: E402
from lpvpc.io import decimate_signal  # noqa: E402
from lpvpc.models import equations as eq  # noqa: E402
from lpvpc.models.basis import NUMPY  # noqa: E402
from lpvpc.models.effects import CATALOG, FRICTION_SCALES, effect_basis, record_context, signals_from_data  # noqa: E402
from lpvpc.simulation.population import draw_subject, simulate_subject  # noqa: E402
from _results import PILOT_POSITION_NOISE, RESULTS, add_position_noise_option, write_results  # noqa: E402
from real_data import real_data_dir  # noqa: E402

FRICTION_SEEDS = range(20000, 20006)  # development seeds of the friction draws
CLEAN_SEEDS = (50003, 50052, 50073, 50085)  # development clean PRBS draws whose friction candidate gained most


def file_rate_features(data):
    """The catalog's friction features from the 1 kHz signals, decimated as the loaders do."""
    high, q = data.high_rate, data.decimation
    v, v_slow = eq.velocity(high.position, high.fs), eq.velocity(high.scheduling, high.fs)
    return np.column_stack([decimate_signal(eq.friction_difference(v, v_slow, s), q) for s in FRICTION_SCALES])


def model_rate_features(data):
    """The catalog entry's own friction features of a record (model-rate velocities)."""
    ctx = record_context(data.position, data.scheduling, data.fs, signals_from_data(data))
    return np.column_stack(CATALOG["nonlinear_viscosity"].features(ctx, NUMPY, {}))


def candidate_gains(model, data, fine):
    """(the catalog candidate, the file-rate features' gain (pp) and p-value, the surrogate and
    its base residual): both sets of friction features scored on ``data`` as the diagnosis
    scores a candidate (the base structure refitted with them, blocked cross-validation);
    ``fine``: the file-rate features of ``data``."""
    sur = Surrogate(model, data)
    r0, _ = sur.cv.fit(sur.base)
    (cand,), _ = score_candidates(sur, candidates=["nonlinear_viscosity"])
    G = effect_basis(CATALOG["nonlinear_viscosity"], model.intrinsic_basis).evaluate(data.scheduling)
    sur.cv.add("fine", eq.kron_rows(fine, G))  # the entry's columns, file-rate features
    r1, _ = sur.cv.fit(sur.base + ["fine"])
    _, p_fine, _ = robust_paired_test(r0, r1, data.fs)
    return cand, 100.0 * (r0 @ r0 - r1 @ r1) / sur.sst, p_fine, sur, r0


def r2(X, y):
    beta = np.linalg.lstsq(X, y, rcond=None)[0]
    e = y - X @ beta
    return 1.0 - (e @ e) / (y @ y)


def draw(seed, noise, effect=True):
    s = draw_subject(seed, effect="nonlinear_viscosity" if effect else None)
    ident, novel = (simulate_subject(s, t, position_noise=noise) for t in ("multilevel", "novel"))
    I, N = lpvpc.pair_trials(ident.pt, ident.ut), lpvpc.pair_trials(novel.pt, novel.ut)
    model = lpvpc.identify(I)
    fine = file_rate_features(N)
    cand, gain_fine, _, sur, r0 = candidate_gains(model, N, fine)
    out = {"seed": seed, "form": s.form or "-", "design": s.design, "model": cand.vaf_gain, "fine": gain_fine}
    if effect:
        clean = simulate_subject(s, "novel", clean=True, position_noise=noise)
        friction = (lpvpc.pair_trials(novel.pt_clean, novel.ut_clean).torque
                    - lpvpc.pair_trials(clean.pt_clean, clean.ut_clean).torque)
        sur.cv.add("truth", friction)
        r1, _ = sur.cv.fit(sur.base + ["truth"])
        out.update(truth=100.0 * (r0 @ r0 - r1 @ r1) / sur.sst, r2_model=r2(model_rate_features(N), friction),
                   r2_fine=r2(fine, friction))
    return out


def pilot_lines() -> list:
    root = real_data_dir()
    path = None if root is None else root / "pilot_ident.csv"
    if path is None or not path.exists():
        return ["", "The lab's pilot trial: skipped (set LPVPC_REAL_DATA or put the lab's recordings in ../shared/real)."]
    d = np.loadtxt(path, delimiter=",", skiprows=1)
    p, tq = d[:, 1], d[:, 2]
    f, P = scipy.signal.welch(p, fs=1000.0, nperseg=4096)
    floor = float(P[(f > 300) & (f < 450)].mean())
    f, C = scipy.signal.coherence(p, tq, fs=1000.0, nperseg=2048)
    bands = [(10, 60), (60, 100), (100, 175), (175, 325), (375, 425)]
    coh = ", ".join(f"{lo}-{hi} Hz {C[(f >= lo) & (f < hi)].mean():.2f}" for lo, hi in bands)
    data = lpvpc.load_identification_data(data=path, torque_sign=-1)
    k = int(0.7 * data.n)
    ident, held = data.segment(0, k), data.segment(k, None)
    cand, gain_fine, p_fine, _, _ = candidate_gains(lpvpc.identify(ident), held, file_rate_features(held))
    return ["", f"The lab's pilot trial ({path.name}, 1 kHz PT - UT position): PSD over 300-450 Hz {floor:.2e} rad^2/Hz, "
                f"a white floor of {np.sqrt(floor * 500.0):.1e} rad RMS ({np.sqrt(floor * 250.0):.1e} in each of the two "
                f"trials); coherence of position and torque: {coh} (sensor noise is incoherent with the torque).",
            f"Its development split (identified on the first 70 %, the candidates scored on the last 30 %): model-rate "
            f"features (the catalog's) {cand.vaf_gain:+.3f} pp (p {cand.p_value:.1e}), file-rate features "
            f"{gain_fine:+.3f} pp (p {p_fine:.1e})."]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_position_noise_option(ap, default=PILOT_POSITION_NOISE)
    args = ap.parse_args(argv)
    cmd = "OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_friction_rate.py" + (
        f" --position-noise {args.position_noise:g}" if args.position_noise != PILOT_POSITION_NOISE else "")
    lines = [f"# Friction features at the file's rate or the model's ({cmd})", "",
             "Held-out VAF gains (pp) as diagnosis candidates on 2-minute population pairs; R^2 of the true friction "
             "torque by each set of features (benchmarks/bench_friction_rate.py's docstring).", "",
             "| seed | form | design | position noise (rad) | R^2 model rate | R^2 file rate | gain: true torque | "
             "gain: model-rate features (the catalog's) | gain: file-rate features |", "|" + "---|" * 9]
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for noise in (0.0, args.position_noise):
            for seed in FRICTION_SEEDS:
                r = draw(seed, noise)
                rows.append(dict(r, noise=noise))
                lines.append(f"| {seed} | {r['form']} | {r['design']} | {noise:g} | {r['r2_model']:.2f} | {r['r2_fine']:.3f} | "
                             f"{r['truth']:+.3f} | {r['model']:+.3f} | {r['fine']:+.3f} |")
        lines += ["", "Clean draws (no friction):", "", "| seed | design | position noise (rad) | gain: model-rate features | "
                  "gain: file-rate features |", "|---|---|---|---|---|"]
        for noise in (0.0, args.position_noise):
            for seed in CLEAN_SEEDS:
                r = draw(seed, noise, effect=False)
                lines.append(f"| {seed} | {r['design']} | {noise:g} | {r['model']:+.3f} | {r['fine']:+.3f} |")
    lines.append("")
    for noise in (0.0, args.position_noise):
        sel = [r for r in rows if r["noise"] == noise]
        share = lambda k: np.median([r[k] / r["truth"] for r in sel])  # noqa: E731
        lines.append(f"position noise {noise:g} rad: median share of the true torque's gain, model-rate features "
                     f"{share('model'):.2f}, file-rate {share('fine'):.2f}; file-rate above model-rate on "
                     f"{sum(r['fine'] > r['model'] for r in sel)}/{len(sel)} draws")
    lines += pilot_lines()
    write_results(RESULTS / "friction_rate.txt", lines, echo=True)


if __name__ == "__main__":
    main()
