"""The lab's five stationary trials through the documented command, as a user runs it.

For each trial of ``experimental_data.mat`` (z_df, z_pf, z_df2, z_df3, z_pf2) the command of
docs/guide/data.md is run twice in a subprocess, as written
(``lpvpc identify experimental_data.mat --variable V --stationary -o M``) and with the sign
the lab's files need (``--torque-sign -1``); the table holds what a user reads: the short-
range stiffness K, the viscosity B, the reflex gain, the relaxed stiffness when stress
relaxation was chosen, the identification VAF, and the warnings' first words (a reversed sign
must be named in one line; a negative B or a relaxed stiffness outside (0, K] flagged).

Skips with a message when the recordings are absent (``benchmarks/real_data.py``).
Writes benchmarks/results/real_stationary_physiology.txt.

Run: OPENBLAS_NUM_THREADS=1 nice python benchmarks/bench_real_stationary_physiology.py
"""

from __future__ import annotations

import numpy as np
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from _results import write_results
from real_data import require

TRIALS = ("z_df", "z_pf", "z_df2", "z_df3", "z_pf2")


def lpvpc_command() -> list:
    """The installed command when on PATH next to this Python, else ``python -m lpvpc.cli``."""
    exe = Path(sys.executable).with_name("lpvpc")
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "lpvpc.cli"]


def run(mat: Path, trial: str, sign: str | None, folder: Path) -> dict:
    from lpvpc import LPVPCModel
    from lpvpc.models.effects import relaxation_stiffnesses

    out = folder / f"{trial}_{sign or 'none'}.json"
    cmd = lpvpc_command() + ["identify", str(mat), "--variable", trial, "--stationary", "-o", str(out)]
    if sign:
        cmd += ["--torque-sign", sign]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    warned = [line.split("warning: ", 1)[1] for line in proc.stderr.splitlines() if "warning: " in line]
    row = {"trial": trial, "sign": sign or "(as documented)", "status": proc.returncode, "warnings": warned}
    if proc.returncode != 0:
        row["error"] = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "?"
        return row
    model = LPVPCModel.load(out)
    s = model.summary().to_dict()
    row.update(K=s["stiffness"][0], B=s["viscosity"][0], gain=s["reflex_gain"][0], vaf=s["vaf"],
               effects=",".join(s["effects"]) or "none")
    if "stress_relaxation" in s["effects"]:
        _, relaxed = relaxation_stiffnesses(model, np.array([model.scheduling_range[0]]))
        row["relaxed"] = float(relaxed[0])
    return row


def _num(x, fmt="{:8.1f}") -> str:
    return fmt.format(x) if isinstance(x, float) else f"{'-':>8}"


def main() -> None:
    mat = require("experimental_data.mat")
    lines = ["# Stationary trials through the documented command (OPENBLAS_NUM_THREADS=1 nice python "
             "benchmarks/bench_real_stationary_physiology.py)",
             "# lpvpc identify experimental_data.mat --variable V --stationary [--torque-sign -1]; K, B, gain at the "
             "operating point; relaxed = the relaxed stiffness when stress relaxation was chosen; warnings: "
             "their first words",
             f"{'trial':6} {'sign':16} {'K N m/rad':>9} {'B N m s/rad':>11} {'gain':>8} {'relaxed':>8} {'VAF %':>7}  "
             "effects            warnings"]
    with tempfile.TemporaryDirectory() as tmp:
        for trial in TRIALS:
            for sign in (None, "-1"):
                r = run(mat, trial, sign, Path(tmp))
                if r["status"]:
                    lines.append(f"{trial:6} {r['sign']:16} error: {r['error']}")
                    continue
                warn = "; ".join(w[:90] for w in r["warnings"]) or "none"
                lines.append(f"{trial:6} {r['sign']:16} {_num(r['K'], '{:9.1f}')} {_num(r['B'], '{:11.2f}')} "
                             f"{_num(r['gain'])} {_num(r.get('relaxed'))} {r['vaf']:7.2f}  {r['effects']:18} {warn}")
    write_results("real_stationary_physiology.txt", lines, echo=True)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    main()
