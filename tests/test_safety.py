"""Nothing lost, nothing run that should not be (issue 14).

Hostile model files are refused with one line (exit 2) before anything is built from
them; outputs never replace inputs; outputs are written atomically and cleaned up on
SIGINT/SIGTERM; external programs get paths, never options; a built FMU is checked;
extra CSV columns of any type are ignored. Every run of a hostile input goes through a
subprocess with a timeout, so a regression fails instead of hanging the suite.
"""

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lpvpc.errors import ModelFileError
from lpvpc.model import LPVPCModel

REPO = Path(__file__).resolve().parents[1]
TIMEOUT = 120  # s: any hostile case must be refused long before this


def _cli(*argv, cwd=None, timeout=TIMEOUT):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "lpvpc.cli", *map(str, argv)], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=timeout)


def _one_line(r):
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, f"expected one stderr line, got {r.stderr[-2000:]!r}"
    assert lines[0].startswith("lpvpc: error: "), lines[0]
    assert "Traceback" not in r.stderr
    return lines[0]


@pytest.fixture(scope="module")
def base(model_file):
    return json.loads(Path(model_file).read_text())


def _set(path, value):
    def change(d):
        *head, last = path
        for k in head:
            d = d[k]
        d[last] = value
    return change


def _unstable(d):
    d["reflex"]["A"] = [[1.5, 0.0], [0.0, 0.5]] if len(d["reflex"]["A"]) == 2 else d["reflex"]["A"]


# (change, words the one-line error must contain)
HOSTILE = {
    "delay-1e5": (_set(("reflex", "delay"), 100_000), "MAX_DELAY"),
    "delay-1e9": (_set(("reflex", "delay"), 10**9), "MAX_DELAY"),
    "delay-3.9": (_set(("reflex", "delay"), 3.9), "integer"),
    "delay-0": (_set(("reflex", "delay"), 0), "reflex.delay"),
    "lag-1e9": (lambda d: d["intrinsic"]["lags"].__setitem__(0, -10**9), "MAX_LAG"),
    "duplicate-lags": (lambda d: d["intrinsic"]["lags"].__setitem__(1, d["intrinsic"]["lags"][0]), "duplicate"),
    "1e6-coefficients": (_set(("intrinsic", "H"), [[0.0] * 900] * 1000), "MAX_COEFFICIENTS"),
    "basis-order-1e6": (_set(("reflex", "velocity_basis", "order"), 10**6), "MAX_BASIS_ORDER"),
    "fs-0": (_set(("fs",), 0), "fs"),
    "fs-negative": (_set(("fs",), -100.0), "fs"),
    "fs-true": (_set(("fs",), True), "fs must be a number"),
    "fs-string": (_set(("fs",), "100"), "fs must be a number"),
    "torque-sign-2": (_set(("conventions", "torque_sign"), 2), "torque_sign"),
    "torque-sign-text": (_set(("conventions", "torque_sign"), "minus"), "torque_sign"),
    "position-unit": (_set(("conventions", "position_unit"), "furlong"), "position_unit"),
    "unstable-reflex": (_unstable, "spectral radius"),
    "huge-coefficient": (lambda d: d["intrinsic"]["H"][0].__setitem__(0, 1e300), "MAX_ABS_VALUE"),
    "bool-coefficient": (lambda d: d["reflex"]["B"].__setitem__(0, True), "must be a number"),
    "string-coefficient": (lambda d: d["reflex"]["Omega"][0].__setitem__(0, "1.0"), "must be a number"),
    "ragged": (lambda d: d["intrinsic"]["H"][0].pop(), "rows of different lengths"),
    "basis-range-reversed": (_set(("intrinsic", "basis", "lo"), 5.0), "MIN_BASIS_SPAN"),
    "basis-extra-field": (_set(("intrinsic", "basis", "evil"), 1), "unknown field"),
    "A-not-square": (_set(("reflex", "A"), [[0.5, 0.1]]), "reflex.A"),
    "settings-order-huge": (_set(("settings", "intrinsic_order"), 10**9), "settings.intrinsic_order"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_model_refused_in_process(case, base):
    change, words = HOSTILE[case]
    d = copy.deepcopy(base)
    change(d)
    with pytest.raises(ModelFileError) as exc:
        LPVPCModel.from_dict(json.loads(json.dumps(d)), source="m.json")
    assert words in str(exc.value) and "\n" not in str(exc.value)


def test_valid_models_still_load(base, model_file):
    m = LPVPCModel.load(model_file)
    assert m.to_dict()["reflex"] == base["reflex"]


def _write_hostile(tmp_path, base, case):
    change, words = HOSTILE[case]
    d = copy.deepcopy(base)
    change(d)
    path = tmp_path / f"{case}.json"
    path.write_text(json.dumps(d))
    return path, words


@pytest.mark.parametrize("case", ["delay-1e5", "1e6-coefficients", "lag-1e9", "unstable-reflex", "fs-true",
                                  "delay-3.9", "torque-sign-text", "huge-coefficient"])
def test_hostile_model_export_refused_quickly(case, base, tmp_path):
    """As a process, with a timeout: exit 2, one line naming the limit, nothing written."""
    path, words = _write_hostile(tmp_path, base, case)
    r = _cli("export", path, "--casadi", tmp_path / "out.casadi", "--fmu", tmp_path / "out.fmu", cwd=tmp_path)
    assert r.returncode == 2, r.stderr[-2000:]
    assert words in _one_line(r)
    assert not (tmp_path / "out.casadi").exists() and not (tmp_path / "out.fmu").exists()


@pytest.mark.parametrize("case", ["fs-0", "torque-sign-2", "position-unit", "unstable-reflex"])
def test_hostile_model_predict_refused(case, base, tmp_path, subject):
    from lpvpc.data import write_trial_csv

    pt, ut = tmp_path / "PT.csv", tmp_path / "UT.csv"
    write_trial_csv(subject["novel_pair"].pt, pt)
    write_trial_csv(subject["novel_pair"].ut, ut)
    path, words = _write_hostile(tmp_path, base, case)
    r = _cli("predict", path, "--pt", pt, "--ut", ut, cwd=tmp_path)
    assert r.returncode == 2 and words in _one_line(r)


def _write_text_model(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_deep_nesting_dev_zero_and_oversized(tmp_path, base):
    deep = _write_text_model(tmp_path, "deep.json", '{"format": "lpvpc-model", "fit": '
                             + "[" * 100_000 + "]" * 100_000 + "}")
    shallow_deep = copy.deepcopy(base)
    shallow_deep["fit"]["x"] = json.loads("[" * 50 + "]" * 50)
    deep2 = _write_text_model(tmp_path, "deep2.json", json.dumps(shallow_deep))
    big = tmp_path / "big.json"
    with open(big, "w") as fh:
        fh.write('{"format": "lpvpc-model", "pad": "')
        fh.write("x" * (9 * 1024 * 1024))
        fh.write('"}')
    dup = _write_text_model(tmp_path, "dup.json", json.dumps(base)[:-1] + ', "fs": 1000.0}')
    for path, words in ((deep, "MAX_NESTING_DEPTH"), (deep2, "MAX_NESTING_DEPTH"), ("/dev/zero", "regular file"),
                        (tmp_path, "regular file"), (big, "MAX_FILE_BYTES"), (dup, "duplicate key")):
        r = _cli("export", path, "--casadi", tmp_path / "o.casadi", cwd=tmp_path, timeout=60)
        assert r.returncode == 2, (path, r.stderr[-500:])
        assert words in _one_line(r), path


def test_fuzz_model_loader_small(base):
    """A few hundred seeded random mutations of a real model: each loads or is refused
    with one line (no other exception). The benchmark runs thousands."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        from bench_fuzz_model import fuzz
    finally:
        sys.path.pop(0)
    result = fuzz(base, n_cases=300, seed=14)
    assert result["tracebacks"] == [], result["tracebacks"][:3]
    assert result["loaded"] + result["refused"] == 300
    assert result["refused"] > 100 and result["loaded"] > 0
