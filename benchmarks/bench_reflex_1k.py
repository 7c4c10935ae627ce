"""Reflex gain and threshold trends from 1 kHz files against 100 Hz files (issue 10, item 3).

For each seed the virtual subject's identification and novel trials are written at 1 kHz
(what a lab records) by the package's writer (``lpvpc.simulation.simulate.write_dataset``), and again
at 100 Hz: the same trials read back, decimated by ``lpvpc.io.decimate_trial`` and written
by ``write_trial_csv`` (a lab's 100 Hz export of the same recording: same noise, so the two
paths differ only in the velocity the reflex nonlinearity sees). Both are read through
``load_identification_data`` with default settings (model rate 100 Hz) and identified at
default settings:

- 1 kHz files: the data keep the 1 kHz position (``PerturbationData.high_rate``) and the
  reflex nonlinearity is identified on the 1 kHz delayed velocity, its output decimated to
  the model rate (``lpvpc.models.reflex.high_rate_input``);
- 100 Hz files: the nonlinearity sees the 100 Hz velocity (its threshold is biased).

Figures per seed: the slopes over the central 80 % of the identified positions of the
rectifier gain and threshold fitted to the identified nonlinearity
(``model.reflex_gain_threshold``), as ratios to the simulator's (1 = exact; target 0.8-1.2);
novel-trajectory VAF of each path on the same novel recording (the 1 kHz model predicting
the novel 1 kHz files, i.e. the high-rate path, and the novel 100 Hz files, i.e. its
model-rate stand-in that the exports use; the 100 Hz model the novel 100 Hz files); load +
identify time of each path (ratio in the same run).

A third identification per seed takes the 1 kHz files with every default (the command line's
``identify``): issue 22 keeps its gain slope within 20 % as a floor and says where its
threshold is not determined. Its structure selection chooses the velocity the nonlinearity
sees (model rate, or 1 kHz with a Chebyshev or hinge basis: lpvpc.identification.selection.compare_reflex_paths);
the table names the choice.

Run: python benchmarks/bench_reflex_1k.py [n_seeds [first_seed]]   (default 10 seeds from 0; writes
     benchmarks/results/reflex_1k.txt, or reflex_1k_seeds<first>-<last>.txt from another first seed)
"""

from __future__ import annotations

import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpvpc.io import decimate_trial, load_identification_data, load_trial, write_trial_csv  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.simulation.simulate import SubjectParams, write_dataset  # noqa: E402

TRUTH = SubjectParams()


def slopes(model):
    lo, hi = model.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 25)
    gain, thr = model.reflex_gain_threshold(rho)
    g = np.polyfit(rho, gain, 1)[0] / np.polyfit(rho, TRUTH.reflex_gain(rho), 1)[0]
    t = np.polyfit(rho, thr, 1)[0] / np.polyfit(rho, TRUTH.reflex_threshold(rho), 1)[0]
    return float(g), float(t)


def load_and_identify(folder):
    t = time.perf_counter()
    data = load_identification_data(pt=folder / "ident_PT.csv", ut=folder / "ident_UT.csv")
    model = identify(data, high_rate_reflex=True)  # opt-in; 100 Hz files have no high-rate signal
    return model, time.perf_counter() - t


def novel(folder):
    return load_identification_data(pt=folder / "novel_PT.csv", ut=folder / "novel_UT.csv")


def one_seed(seed, tmp):
    out = {"seed": seed}
    dirs = {1000: Path(tmp) / f"s{seed}_1000", 100: Path(tmp) / f"s{seed}_100"}
    write_dataset(dirs[1000], seed=seed, fs_out=1000.0)
    dirs[100].mkdir()
    for stem in ("ident_PT", "ident_UT", "novel_PT", "novel_UT"):
        write_trial_csv(decimate_trial(load_trial(dirs[1000] / f"{stem}.csv"), 100.0), dirs[100] / f"{stem}.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m1k, out["t1k"] = load_and_identify(dirs[1000])
        m100, out["t100"] = load_and_identify(dirs[100])
        n1k, n100 = novel(dirs[1000]), novel(dirs[100])
        out["vaf_1k"] = vaf(n1k.torque, m1k.predict(n1k).total)            # high-rate path
        out["vaf_1k_model_rate"] = vaf(n100.torque, m1k.predict(n100).total)  # stand-in (exports)
        out["vaf_100"] = vaf(n100.torque, m100.predict(n100).total)
        t = time.perf_counter()  # every default (the command line's identify): issue 22's floor on the gain
        mdef = identify(load_identification_data(pt=dirs[1000] / "ident_PT.csv", ut=dirs[1000] / "ident_UT.csv"))
        out["tdef"] = time.perf_counter() - t
        path = mdef.fit.get("structure_selection", {}).get("reflex_path")
        out["path"] = path["label"] if path else "not selected"
    assert m1k.high_rate is not None and m100.high_rate is None
    out["gdef"], out["tdef_slope"] = slopes(mdef)
    lo, hi = mdef.scheduling_range
    rho = np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 9)
    for key, m in (("def", mdef), ("1k", m1k)):
        g_ok, th_ok = m.reflex_determined(rho)
        out[f"gdet_{key}"], out[f"thdet_{key}"] = float(np.mean(g_ok)), float(np.mean(th_ok))
    out["g1k"], out["t1k_slope"] = slopes(m1k)
    out["g100"], out["t100_slope"] = slopes(m100)
    return out


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    first = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    t0 = time.time()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in range(first, first + n):
            rows.append(one_seed(s, tmp))
            print(rows[-1], flush=True)
    a = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    within = lambda x: int(np.sum((x > 0.8) & (x < 1.2)))  # noqa: E731
    lines = [
        f"# Reflex trends from 1 kHz files vs 100 Hz files (python benchmarks/bench_reflex_1k.py {n} {first})", "",
        "Slope over position of the identified rectifier gain / threshold as a ratio to the simulator's",
        "(1 = exact, target 0.8-1.2). Files written by lpvpc.simulation.simulate.write_dataset, read by",
        "load_identification_data with default settings (model rate 100 Hz), identified with defaults.",
        "'1 kHz': the nonlinearity on the 1 kHz delayed velocity (PerturbationData.high_rate), decimated;",
        "'100 Hz': on the 100 Hz velocity. Novel VAF (%): '1 kHz' predicts the novel 1 kHz files (high-rate",
        "path); '1 kHz model, 100 Hz files' uses the model-rate stand-in the CasADi/FMU exports carry.",
        "Time: load + identify (s), both paths in the same run.", "",
        "'defaults, 1 kHz files': identify(data) with every default (the command line's), whatever velocity",
        "the default's structure selection gives the nonlinearity ('default path'); 'determined': fraction of 9 central",
        "positions where the gain / threshold is determined (lpvpc.models.reflex_uncertainty.reflex_determination).", "",
        "| seed | gain 1 kHz | threshold 1 kHz | gain 100 Hz | threshold 100 Hz | gain defaults, 1 kHz files | "
        "threshold defaults, 1 kHz files | default path | determined gain/threshold: defaults | 1 kHz | "
        "novel VAF 1 kHz | novel VAF 1 kHz model, 100 Hz files | novel VAF 100 Hz | time 1 kHz | time 100 Hz | "
        "time defaults, 1 kHz files |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['seed']} | {r['g1k']:.2f} | {r['t1k_slope']:.2f} | {r['g100']:.2f} | {r['t100_slope']:.2f} | "
                     f"{r['gdef']:.2f} | {r['tdef_slope']:.2f} | {r['path']} | {r['gdet_def']:.2f}/{r['thdet_def']:.2f} | "
                     f"{r['gdet_1k']:.2f}/{r['thdet_1k']:.2f} | "
                     f"{r['vaf_1k']:.2f} | {r['vaf_1k_model_rate']:.2f} | {r['vaf_100']:.2f} | {r['t1k']:.1f} | "
                     f"{r['t100']:.1f} | {r['tdef']:.1f} |")
    lines += [
        "",
        f"seeds: {first}..{first + n - 1}",
        "default path: " + ", ".join(f"{k} {sum(r['path'] == k for r in rows)}" for k in sorted({r['path'] for r in rows})),
        f"gain slope ratio: 1 kHz median {np.median(a['g1k']):.2f} (range {a['g1k'].min():.2f}..{a['g1k'].max():.2f}, "
        f"within 20 % on {within(a['g1k'])}/{n}); 100 Hz median {np.median(a['g100']):.2f} "
        f"(within 20 % on {within(a['g100'])}/{n})",
        f"gain slope ratio at every default from 1 kHz files (the floor: within 20 %): median "
        f"{np.median(a['gdef']):.2f} (range {a['gdef'].min():.2f}..{a['gdef'].max():.2f}, within 20 % on "
        f"{within(a['gdef'])}/{n}); its threshold slope median {np.median(a['tdef_slope']):.2f}, determined at "
        f"{100 * np.mean(a['thdet_def']):.0f} % of positions (gain at {100 * np.mean(a['gdet_def']):.0f} %); "
        f"1 kHz path: threshold determined at {100 * np.mean(a['thdet_1k']):.0f} %, gain at "
        f"{100 * np.mean(a['gdet_1k']):.0f} %",
        f"threshold slope ratio: 1 kHz median {np.median(a['t1k_slope']):.2f} (range {a['t1k_slope'].min():.2f}.."
        f"{a['t1k_slope'].max():.2f}, within 20 % on {within(a['t1k_slope'])}/{n}); 100 Hz median "
        f"{np.median(a['t100_slope']):.2f} (within 20 % on {within(a['t100_slope'])}/{n})",
        f"novel VAF: 1 kHz path minus 100 Hz path median {np.median(a['vaf_1k'] - a['vaf_100']):+.3f} points "
        f"(min {np.min(a['vaf_1k'] - a['vaf_100']):+.3f}); model-rate stand-in minus 100 Hz path median "
        f"{np.median(a['vaf_1k_model_rate'] - a['vaf_100']):+.3f} (min {np.min(a['vaf_1k_model_rate'] - a['vaf_100']):+.3f})",
        f"load + identify time ratio 1 kHz / 100 Hz: median {np.median(a['t1k'] / a['t100']):.2f}x "
        f"(max {np.max(a['t1k'] / a['t100']):.2f}x; floor 3x)",
        f"total time {time.time() - t0:.0f} s",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    name = "reflex_1k.txt" if first == 0 else f"reflex_1k_seeds{first}-{first + n - 1}.txt"
    (ROOT / "benchmarks" / "results" / name).write_text(text)


if __name__ == "__main__":
    main()
