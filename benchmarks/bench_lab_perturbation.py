"""The virtual subject under the lab's own perturbation design (issue 10, items 1 and 3).

The lab's pilot trial does not use the virtual subject's PRALDS (levels uniform in +-40 mrad:
steps of every size). Its perturbation alternates between 0 and a pulse level of 20-42 mrad
(``lpvpc.simulation.simulate.lab_pulses``, measured on ``pilot_ident.csv``): every step is large, so
every stretch reaches a peak velocity of a few rad/s, far above a reflex threshold of a few
tenths of a rad/s. Which reflex-nonlinearity paths still recover the reflex trends then?

For each seed, 1 kHz files of both designs (``write_dataset(perturbation=...)``), identified
three ways: the default (nonlinearity on the 100 Hz velocity), the opt-in 1 kHz path with its
default hinge basis of order 8, and the 1 kHz path with a Chebyshev basis of order 4 (the
variant that held up on the pilot trial: benchmarks/results/real_pilot.txt). Figures: slope
ratios of the rectifier gain and threshold to the simulator's (target 0.8-1.2, as
bench_reflex_1k), the share of central positions where the identified gain is negative
(a stretch reflex that lowers the torque: not physiological), and novel-trajectory VAF (%).
When the lab's recordings are present, the velocity pulses of the simulated lab design are
compared with the pilot's (median peak |velocity|, width at half height, interval).

Run: python benchmarks/bench_lab_perturbation.py [n_seeds]   (default 8; ~2 min; writes
     benchmarks/results/lab_perturbation.txt)
"""

from __future__ import annotations

import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import scipy.signal

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from _results import write_results  # noqa: E402
from bench_reflex_1k import slopes  # noqa: E402
from real_data import real_data_dir  # noqa: E402

from lpvpc.io import load_identification_data, load_trial  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.simulation.simulate import simulate_pair, write_dataset  # noqa: E402

DESIGNS = ("pralds", "lab_pulses")
PATHS = {
    "100 Hz velocity (default)": {},
    "1 kHz, hinge 8 (opt-in default)": {"high_rate_reflex": True},
    "1 kHz, Chebyshev 4": {"high_rate_reflex": True, "high_rate_velocity_basis": "chebyshev",
                           "high_rate_velocity_order": 4},
}


def pulse_stats(position, fs):
    """(median peak |velocity| rad/s, median width at half height ms, median interval ms) of
    the perturbation's velocity pulses."""
    v = np.gradient(position) * fs
    peaks, _ = scipy.signal.find_peaks(np.abs(v), height=0.3 * np.percentile(np.abs(v), 99.9), distance=int(0.03 * fs))
    widths = scipy.signal.peak_widths(np.abs(v), peaks, rel_height=0.5)[0] / fs
    return float(np.median(np.abs(v[peaks]))), 1e3 * float(np.median(widths)), 1e3 * float(np.median(np.diff(peaks)) / fs)


def one(seed, design, tmp):
    folder = Path(tmp) / f"{design}_{seed}"
    write_dataset(folder, seed=seed, fs_out=1000.0, perturbation=design)
    data = load_identification_data(pt=folder / "ident_PT.csv", ut=folder / "ident_UT.csv")
    novel = load_identification_data(pt=folder / "novel_PT.csv", ut=folder / "novel_UT.csv")
    out = {}
    for name, settings in PATHS.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = identify(data, **settings)
            lo, hi = m.scheduling_range
            gain, _ = m.reflex_gain_threshold(np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 25))
            out[name] = (*slopes(m), float(np.mean(gain < 0)), vaf(novel.torque, m.predict(novel).total))
    return out


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 8
    t0 = time.time()
    within = lambda x: int(np.sum((x > 0.8) & (x < 1.2)))  # noqa: E731
    results = {d: {p: [] for p in PATHS} for d in DESIGNS}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(n):
            for design in DESIGNS:
                for path, row in one(seed, design, tmp).items():
                    results[design][path].append(row)
            print(f"seed {seed} done", flush=True)
    lines = ["# The virtual subject under the lab's perturbation design (python benchmarks/bench_lab_perturbation.py)",
             f"# {n} seeds, 1 kHz files, 2-minute records at 18 dB; slope ratios to the simulator's (target 0.8-1.2);",
             "# 'gain < 0': share of central positions with a negative identified reflex gain; novel VAF % (median)",
             "| perturbation | reflex nonlinearity | gain slope within 20 % | gain slope median | threshold slope within 20 % "
             "| threshold slope median | seeds with gain < 0 somewhere | novel VAF |",
             "|---|---|---|---|---|---|---|---|"]
    for design in DESIGNS:
        for path in PATHS:
            a = np.array(results[design][path])
            lines.append(f"| {design} | {path} | {within(a[:, 0])}/{n} | {np.median(a[:, 0]):.2f} | {within(a[:, 1])}/{n} | "
                         f"{np.median(a[:, 1]):.2f} | {int(np.sum(a[:, 2] > 0))}/{n} | {np.median(a[:, 3]):.2f} |")
    lines.append("")
    sim = {d: simulate_pair("multilevel", seed=0, duration=60.0, perturbation=d) for d in DESIGNS}
    for design, pair in sim.items():
        s = pulse_stats(pair.pt.position - pair.ut.position, 1000.0)
        lines.append(f"velocity pulses, virtual subject {design}: peak {s[0]:.2f} rad/s, width {s[1]:.1f} ms, interval {s[2]:.0f} ms")
    folder = real_data_dir()
    if folder is not None and (folder / "pilot_ident.csv").is_file():
        pilot = load_trial(folder / "pilot_ident.csv")
        s = pulse_stats(pilot.position, pilot.fs)
        lines.append(f"velocity pulses, lab pilot trial (pilot_ident.csv): peak {s[0]:.2f} rad/s, width {s[1]:.1f} ms, "
                     f"interval {s[2]:.0f} ms")
    else:
        lines.append("lab pilot trial not found (set LPVPC_REAL_DATA): no comparison with its pulses")
    lines.append(f"total time {time.time() - t0:.0f} s")
    write_results("lab_perturbation.txt", lines, echo=True)


if __name__ == "__main__":
    main()
