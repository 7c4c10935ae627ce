"""Bounded loading (issue 26): memory and time of reading a trial from a .mat file that also
holds an unrelated variable declaring far more data than it holds, against the same file
without it; and the cost of the output policy's check.

Files (written here, 2 minutes of a 1 kHz virtual-subject trial as a struct ``pt``):
- clean -v7.3 (mat-io) and the same plus ``junk``, an HDF5 dataset declaring 10^9 doubles
  (7.45 GiB) with no data written (the file stays under 4 MB);
- clean compressed v5 (scipy) and the same plus a 60-byte compressed element declaring 4e8
  doubles (2.98 GiB).

Each read runs in a fresh process (``load_trial(path + ":pt")``, the junk by name, the file without a variable named,
and so with the limit lifted: what the reader did before it had one) that reports its peak
resident memory (ru_maxrss) and the read's wall time; a 4 GiB address-space limit keeps a
regression from taking the machine. The output policy's check is timed in-process over a
refused command (every input form x output option of ``improve``, as in
tests/test_output_policy.py, is what one refusal costs).

    python benchmarks/bench_bounded_loading.py

Prints a table and writes benchmarks/results/bounded_loading.txt. Timings are
machine-dependent (shared, noisy machines): compare ratios within one run.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))

from _results import write_results  # noqa: E402

CHILD = """
import resource, sys, time
t0 = time.perf_counter()
from lpvpc.io import load_trial
t1 = time.perf_counter()
try:
    n = load_trial(sys.argv[1]).time.size
    outcome = f"{n} samples"
except Exception as exc:
    text = str(exc).replace(sys.argv[1].partition(".mat")[0] + ".mat: ", "")
    outcome = type(exc).__name__ + ": " + (text[:50] + " ... " + text[-60:] if len(text) > 110 else text)
t2 = time.perf_counter()
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, t2 - t1, outcome, sep="|")
"""


def _child(path, extra_env=None):
    limit = 4 << 30

    def rlimit():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(HERE.parent), **(extra_env or {}))
    r = subprocess.run([sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, env=env,
                       timeout=600, preexec_fn=rlimit)
    if r.returncode != 0:
        return float("nan"), float("nan"), f"exit {r.returncode}: {r.stderr.strip().splitlines()[-1][:60]}"
    rss, seconds, outcome = r.stdout.strip().split("|")
    return float(rss), float(seconds), outcome


def main():
    import h5py
    import scipy.io
    from matlab_files import write_mat
    from test_safety import _v5_compressed_junk

    from lpvpc.simulation.simulate import simulate_pair

    pair = simulate_pair("multilevel", seed=0)
    tr = pair.pt
    struct = {"pt": {"time": tr.time, "position": tr.position, "torque": tr.torque}}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        files = {}
        files["v7.3 clean"] = write_mat(tmp / "clean73.mat", struct, version="v7.3")
        files["v7.3 + 10^9 declared"] = write_mat(tmp / "junk73.mat", struct, version="v7.3")
        with h5py.File(files["v7.3 + 10^9 declared"], "a") as f:
            ds = f.create_dataset("junk", shape=(1, 10**9), dtype="f8", chunks=(1, 10**6))
            ds.attrs["MATLAB_class"] = np.bytes_("double")
        files["v5 clean"] = tmp / "clean5.mat"
        scipy.io.savemat(files["v5 clean"], struct, do_compression=True)
        files["v5 + 4e8 declared"] = tmp / "junk5.mat"
        files["v5 + 4e8 declared"].write_bytes(files["v5 clean"].read_bytes() + _v5_compressed_junk())
        for name, path in files.items():
            reads = [("pt", f"{path}:pt", None)]
            if "clean" not in name:  # the junk itself; found automatically; and with no limit (the old reader)
                reads += [("junk", f"{path}:junk", None), ("auto", str(path), None),
                          ("auto, no limit", str(path), {"LPVPC_MAX_VARIABLE_BYTES": "1e15"})]
            for what, arg, env in reads:
                rss, seconds, outcome = _child(arg, env)
                rows.append((name, path.stat().st_size, what, rss, seconds, outcome))

        from lpvpc.cli import COMMAND_IO, build_parser

        args = build_parser().parse_args(["improve", "--pt", "PT.csv", "--ut", "UT.csv", "--heldout-pt", "PT.csv",
                                          "--heldout-ut", "UT.csv", "--report", str(tmp / "rep"), "-o",
                                          str(tmp / "m.json")])
        n = 2000
        t0 = time.perf_counter()
        for _ in range(n):
            COMMAND_IO["improve"].check(args)
        check_us = (time.perf_counter() - t0) / n * 1e6
    base = {r[0].split()[0]: r for r in rows if "clean" in r[0]}
    lines = [f"Bounded loading: reading the struct 'pt' (120 s at 1 kHz) from a .mat file, each read in a fresh "
             f"process (python {sys.version.split()[0]}, 4 GiB address-space limit)",
             "",
             f"{'file':24} {'size':>9} {'read':>14} {'peak RSS MB':>12} {'x clean':>8} {'read s':>7}  outcome"]
    for name, size, what, rss, seconds, outcome in rows:
        ratio = rss / base[name.split()[0]][3]
        lines.append(f"{name:24} {size / 1e6:7.2f} MB {what:>14} {rss:12.0f} {ratio:8.2f} {seconds:7.3f}  {outcome}")
    lines += ["", f"output policy check (improve: 4 inputs, 2 files, 1 folder): {check_us:.0f} us per command"]
    write_results("bounded_loading.txt", lines, echo=True)


if __name__ == "__main__":
    main()
