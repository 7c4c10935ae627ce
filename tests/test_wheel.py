"""The package as a new user gets it: a built wheel installed into a fresh venv outside the
checkout exports FMI 2.0 and 3.0 FMUs, which fmpy simulates, and validates a model.

The venv is made with the running interpreter and no system site packages; the wheel is
installed without its dependencies, which come from the running environment through a
``.pth`` line (a path line only: that environment's own ``.pth`` files, among them the
editable install of this checkout, are not processed), so `import lpvpc` can only find the
wheel's copy. ``pip check`` then confirms the wheel's declared dependencies are met. This
keeps the test at seconds instead of a download of casadi and scipy; a full ``pip install
<wheel>`` resolves the same declared requirements.
"""

import json
import os
import subprocess
import sys
import sysconfig
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _run(cmd, cwd, timeout=600, env=None):
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env=env)
    assert proc.returncode == 0, f"$ {' '.join(map(str, cmd))}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


@pytest.fixture(scope="module")
def wheel_venv(tmp_path_factory):
    """(python, lpvpc entry point, work dir) of a fresh venv with the built wheel."""
    base = tmp_path_factory.mktemp("wheel")
    dist = base / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", dist, REPO],
         cwd=base)
    wheels = sorted(dist.glob("lpvpc-*.whl"))
    assert len(wheels) == 1, wheels
    venv = base / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=base)
    py = venv / "bin" / "python"
    site = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=base).strip())
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "_lpvpc_test_deps.pth").write_text("\n".join(sorted(deps)) + "\n")
    _run([sys.executable, "-m", "pip", "--python", py, "install", "-q", "--no-deps", wheels[0]], cwd=base)
    _run([sys.executable, "-m", "pip", "--python", py, "check"], cwd=base)
    work = base / "work"
    work.mkdir()
    return py, venv / "bin" / "lpvpc", work


@pytest.mark.slow
def test_wheel_ships_sources_and_exports_and_simulates_both_fmi_versions(wheel_venv, model):
    py, lpvpc, work = wheel_venv
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "LPVPC_FMU_MODELS")}
    where = _run([py, "-c", "import lpvpc, lpvpc.validation, lpvpc.export.fmu_build as b; "
                            "print(lpvpc.__file__); print(lpvpc.validation.__file__); print(b.wrapper_dir())"],
                 cwd=work, env=env).split()
    for path in where:  # everything comes from the venv, nothing from the checkout
        assert str(REPO) not in path and str(py.parents[1]) in path, where
    model.save(work / "model.json")
    for fmi in (2, 3):
        _run([lpvpc, "export", "model.json", "--fmu", f"m{fmi}.fmu", "--fmi", fmi], cwd=work, env=env)
        assert (work / f"m{fmi}.fmu").is_file()
    script = textwrap.dedent("""
        import json, sys
        import numpy as np
        from fmpy import read_model_description, simulate_fmu
        from fmpy.validation import validate_fmu
        from lpvpc.export import exporter as ex
        from lpvpc.simulation import simulate
        from lpvpc.models.model import LPVPCModel
        model = LPVPCModel.load("model.json")
        t = np.arange(600) / model.fs
        position = 0.02 * np.sin(2 * np.pi * 3.0 * t)
        scheduling = -0.1 + 0.1 * np.sin(2 * np.pi * 0.2 * t)
        rows = ex.replay_inputs(model, position, scheduling, ex.DEFAULT_FMU_VARIANT)  # what `export --fmu` made
        names = list(rows)
        signals = np.zeros(len(t), dtype=[("time", float)] + [(n, float) for n in names])
        signals["time"] = t
        for n in names:
            signals[n] = rows[n].ravel()
        out = {}
        for fmi in (2, 3):
            path = f"m{fmi}.fmu"
            problems = validate_fmu(path)
            md = read_model_description(path)
            lat = round(next(float(v.start) for v in md.modelVariables if v.name == "latency") * model.fs)
            res = simulate_fmu(path, input=signals, output=["torque"], step_size=1 / model.fs,
                               output_interval=1 / model.fs, stop_time=t[-1] + (lat + 1) / model.fs)
            y = np.asarray(res["torque"])[lat + 1:]  # the timing contract (README): sample k at t_k + L + T
            ref = model.predict(position, scheduling, causal=True, warn=False).total
            assert np.max(np.abs(y - ref)) < 1e-9 * np.max(np.abs(ref)), np.max(np.abs(y - ref))
            out[fmi] = {"problems": list(problems), "n": len(y), "finite": bool(np.all(np.isfinite(y))),
                        "std": float(np.std(y))}
        print(json.dumps(out))
    """)
    res = json.loads(_run([py, "-c", script], cwd=work, env=env).strip().splitlines()[-1])
    for fmi in ("2", "3"):
        r = res[fmi]
        assert r["problems"] == [] and r["finite"] and r["n"] == 600 and r["std"] > 1e-3, (fmi, r)


@pytest.mark.slow
def test_wheel_validates_a_model_with_fmi3(wheel_venv, model, subject):
    """`lpvpc validate` (routes, co-simulation with the actuator FMU built from the wheel's
    sources, report) from outside the checkout."""
    py, lpvpc, work = wheel_venv
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "LPVPC_FMU_MODELS")}
    env["LPVPC_CACHE"] = str(work / "cache")  # the actuator FMU is built from the installed sources
    model.save(work / "model.json")
    pair = subject["novel_pair"]
    from lpvpc.io import write_trial_csv

    write_trial_csv(pair.pt, work / "PT.csv")
    write_trial_csv(pair.ut, work / "UT.csv")
    _run([lpvpc, "validate", "model.json", "--pt", "PT.csv", "--ut", "UT.csv", "--report", "rep", "--fmi", 3],
         cwd=work, env=env)
    metrics = json.loads((work / "rep" / "metrics.json").read_text())
    assert (work / "rep" / "report.html").is_file()
    assert any(str(k).startswith("vaf") for k in metrics), list(metrics)[:20]
