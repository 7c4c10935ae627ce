"""The portable SSP in libcosim and ECOS on the whole novel record.

    python benchmarks/bench_portable_ssp.py

Identifies the model on the virtual subject (multilevel seed 0, 2 min, 100 Hz), runs
``validate`` (default settings) on the novel trajectory (``simulate_pair("novel", seed=1)``,
2 min at 1 kHz), then runs the report's ``cosimulation_portable.ssp`` in each engine that is
installed and compares its model-torque VAF with the harness's co-simulation. Prints a table and
writes it to ``benchmarks/results/portable_ssp.txt``. Units: %, s.
"""

from __future__ import annotations

import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lpvpc.io import pair_trials  # noqa: E402
from lpvpc.identification.identify import identify  # noqa: E402
from lpvpc.models.model import vaf  # noqa: E402
from lpvpc.simulation.simulate import simulate_pair  # noqa: E402
from lpvpc.validation import validate  # noqa: E402
from lpvpc.validation.engines import ENGINES, available, run_portable_ssp  # noqa: E402
from _results import write_results  # noqa: E402


def main():
    ident, novel = simulate_pair("multilevel", seed=0), simulate_pair("novel", seed=1)
    model = identify(pair_trials(ident.pt, ident.ut))
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        result = validate(model, novel.pt, novel.ut, Path(tmp) / "report", measure_load_effect=False)
        t_validate = time.perf_counter() - t0
        m = result.metrics
        meas = pair_trials(novel.pt, novel.ut, target_fs=model.fs)
        L = m["cosim"]["model_fmu_latency_samples"]
        lines = ["Portable SSP (cosimulation_portable.ssp of lpvpc validate) on the 2-minute novel record",
                 f"harness co-simulation VAF {m['vaf_cosim']:.2f} %, offline {m['vaf']:.2f} %; validate "
                 f"{t_validate:.1f} s (record-player FMU {m['timing_s'].get('portable_ssp', float('nan')):.1f} s)",
                 "", f"{'engine':>9} {'VAF %':>7} {'- harness':>9} {'run s':>6}"]
        for engine in ENGINES:
            why = available(engine)
            if why:
                lines.append(f"{engine:>9}  not run: {why}")
                continue
            t0 = time.perf_counter()
            y = run_portable_ssp(result.files["portable_ssp"], engine)[L:L + meas.n]
            dt = time.perf_counter() - t0
            v = vaf(meas.torque, y)
            lines.append(f"{engine:>9} {v:7.2f} {v - m['vaf_cosim']:+9.2f} {dt:6.1f}")
    lines += ["", f"{platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}"]
    write_results("portable_ssp.txt", lines, echo=True)


if __name__ == "__main__":
    main()
