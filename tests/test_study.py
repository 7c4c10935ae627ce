"""lpvpc study: the manifest's checks, fault isolation, the content cache, and the same
tables from one process, a process pool and a Dask cluster.

One small virtual cohort (6 subjects, 40-s records at 100 Hz) with three bad records added
(a missing file, a trial in degrees, PT and UT swapped) and one too short for its held-out
part; the serial study is run once and the others are compared with it.
"""

import csv
import json
import math
import re
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from lpvpc.cli import main
from lpvpc.study import ManifestError, read_manifest, run_study
from lpvpc.study.cohort import write_cohort

#: The bad records and a word of their reason. The missing file fails before a job is run
#: (its content cannot be hashed): the others are attempted (counted as computed) and fail.
BAD = {"B_missing": "file not found", "B_degrees": "degree", "B_swapped": "swap", "B_short": "held-out part"}


def _rewrite(src, dst, rows=None, scale_position=1.0):
    lines = src.read_text().splitlines()
    header, body = lines[0], lines[1:]
    if rows is not None:
        body = body[:rows]
    cols = header.split(",")
    out = [header]
    for line in body:
        cells = line.split(",")
        for name in ("position", "command"):
            if name in cols:
                i = cols.index(name)
                cells[i] = repr(float(cells[i]) * scale_position)
        out.append(",".join(cells))
    dst.write_text("\n".join(out) + "\n")


@pytest.fixture(scope="module")
def cohort(tmp_path_factory):
    """The cohort's folder; its manifest.csv (6 good records) and bad.csv (those and 4 bad ones)."""
    root = tmp_path_factory.mktemp("cohort")
    paths = write_cohort(root, 6, duration=40.0, fs=100.0)
    bad = root / "bad"
    bad.mkdir()
    _rewrite(root / "S01" / "PT.csv", bad / "PT_deg.csv", scale_position=180 / math.pi)
    _rewrite(root / "S01" / "UT.csv", bad / "UT_deg.csv", scale_position=180 / math.pi)
    _rewrite(root / "S03" / "PT.csv", bad / "PT_short.csv", rows=1500)
    _rewrite(root / "S03" / "UT.csv", bad / "UT_short.csv", rows=1500)
    text = paths["manifest"].read_text()
    text += ("B_missing,S01,control,nowhere/PT.csv,S01/UT.csv\n"
             "B_degrees,S01,control,bad/PT_deg.csv,bad/UT_deg.csv\n"
             "B_swapped,S02,patient,S02/UT.csv,S02/PT.csv\n"
             "B_short,S03,control,bad/PT_short.csv,bad/UT_short.csv\n")
    (root / "bad.csv").write_text(text)
    return root


@pytest.fixture(scope="module")
def serial(cohort, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    return out, run_study(cohort / "bad.csv", out, jobs=1)


def _table(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _assert_same_tables(a, b, tol=1e-12, skip=("cached",)):
    """records.csv and groups.csv of two study folders agree: text cells equal, numbers to
    ``tol`` (columns ``skip`` not compared)."""
    for name in ("records.csv", "groups.csv"):
        ta, tb = _table(a / name), _table(b / name)
        assert len(ta) == len(tb) > 0
        for ra, rb in zip(ta, tb):
            assert ra.keys() == rb.keys()
            for k in ra:
                if k in skip:
                    continue
                try:
                    xa, xb = float(ra[k]), float(rb[k])
                except ValueError:
                    assert ra[k] == rb[k], (name, k)
                    continue
                assert abs(xa - xb) <= tol * max(1.0, abs(xa)), (name, k, xa, xb)


# --------------------------------------------------------------------------- manifest
MANIFESTS = {
    "missing column": ("record,subject,pt,ut\nA,S1,p.csv,u.csv\n", ["row 1", "'group'"]),
    "unknown column": ("record,subject,group,pt,ut,torque_sgn\nA,S1,G,p.csv,u.csv,1\n", ["row 1", "torque_sgn"]),
    "empty subject": ("record,subject,group,pt,ut\nA,S1,G,p.csv,u.csv\nB,,G,p.csv,u.csv\n",
                      ["row 3", "record 'B'", "column subject"]),
    "duplicate record": ("record,subject,group,pt,ut\nA,S1,G,p.csv,u.csv\nA,S2,G,p.csv,u.csv\n",
                         ["row 3", "column record", "row 2"]),
    "no ut": ("record,subject,group,pt,ut\nA,S1,G,p.csv,\n", ["row 2", "column ut"]),
    "data and pt": ("record,subject,group,pt,ut,data\nA,S1,G,p.csv,u.csv,d.csv\n", ["row 2", "column data"]),
    "torque sign": ("record,subject,group,pt,ut,torque_sign\nA,S1,G,p.csv,u.csv,2\n", ["row 2", "torque_sign", "'2'"]),
    "unit": ("record,subject,group,pt,ut,position_unit\nA,S1,G,p.csv,u.csv,grad\n", ["row 2", "position_unit"]),
    "heldout": ("record,subject,group,pt,ut,heldout\nA,S1,G,p.csv,u.csv,30\n", ["row 2", "heldout", "'30'"]),
    "stationary": ("record,subject,group,pt,ut,stationary\nA,S1,G,p.csv,u.csv,maybe\n", ["row 2", "stationary"]),
    "diagnose": ("record,subject,group,pt,ut,diagnose\nA,S1,G,p.csv,u.csv,perhaps\n", ["row 2", "diagnose", "'perhaps'"]),
    "record name": ("record,subject,group,pt,ut\na/b,S1,G,p.csv,u.csv\n", ["row 2", "column record"]),
    "no rows": ("record,subject,group,pt,ut\n", ["no records"]),
    "empty": ("", ["empty"]),
}


@pytest.mark.parametrize("case", sorted(MANIFESTS))
def test_bad_manifest_is_one_line_naming_row_and_column(case, tmp_path, capsys):
    text, words = MANIFESTS[case]
    path = tmp_path / "m.csv"
    path.write_text(text)
    with pytest.raises(ManifestError) as info:
        read_manifest(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    assert all(w in message for w in words), message
    # the command line: one line, exit 2, nothing run
    assert main(["-q", "study", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lpvpc: error: ") and words[0] in err[0]


def test_manifest_reads_settings_and_paths_relative_to_it(tmp_path):
    (tmp_path / "m.csv").write_text("record,subject,group,pt,ut,torque_sign,position_unit,stationary,heldout\n"
                                    "A,S1,G,x/p.csv,x/u.csv,-1,deg,,0.25\nB,S1,G,q.csv,,,,true,\n")
    a, b = read_manifest(tmp_path / "m.csv")
    assert a.pt == str((tmp_path / "x" / "p.csv").resolve()) and a.torque_sign == -1.0
    assert (a.position_unit, a.heldout, a.stationary) == ("deg", 0.25, False)
    assert b.stationary and b.ut is None and b.heldout is None


# --------------------------------------------------------------------------- the study
def test_bad_records_are_named_and_the_others_finish(serial, cohort):
    out, result = serial
    assert result.failed == len(BAD) and result.exit_status == 1
    failures = dict(result.failures())
    assert set(failures) == set(BAD)
    for record, word in BAD.items():
        assert word in failures[record].lower(), (record, failures[record])
        assert "\n" not in failures[record]
    ok = [r for r in result.results if r["status"] == "ok"]
    assert len(ok) == 6 and all(r["vaf_heldout"] > 0 for r in ok)
    # records.csv: the failed records with their reason, the others on the common grid
    rows = _table(out / "records.csv")
    assert {r["record"] for r in rows if r["status"] == "failed"} == set(BAD)
    theta = sorted({float(r["theta"]) for r in rows if r["status"] == "ok"})
    lo = max(r["range"][0] for r in ok)
    hi = min(r["range"][1] for r in ok)
    assert len(theta) >= 5 and lo - 1e-9 <= theta[0] and theta[-1] <= hi + 1e-9
    # groups.csv: the difference patient - control with its interval around it
    diff = [r for r in _table(out / "groups.csv") if r["group"] == "patient - control" and r["quantity"] == "stiffness"]
    assert len(diff) == len(theta)
    assert all(float(r["lower"]) <= float(r["mean"]) <= float(r["upper"]) for r in diff)
    # the report holds the failed records and the figures, and nothing outside itself
    html = (out / "report.html").read_text()
    assert all(rec in html for rec in BAD) and "data:image/png;base64," in html
    assert "src=\"http" not in html and "href=\"http" not in html


def test_group_statistics_are_over_subjects(serial):
    """The group mean at a position is the mean of the subjects' values (each subject's
    sessions averaged first), and the interval the t interval over them."""
    from scipy import stats

    out, result = serial
    rows = [r for r in _table(out / "records.csv") if r["status"] == "ok"]
    theta = rows[0]["theta"]
    per = {}
    for r in rows:
        if r["theta"] == theta:
            per.setdefault(r["group"], {}).setdefault(r["subject"], []).append(float(r["stiffness"]))
    g = next(r for r in _table(out / "groups.csv") if r["quantity"] == "stiffness" and r["theta"] == theta
             and r["group"] == "control")
    x = np.array([np.mean(v) for v in per["control"].values()])
    h = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x))
    assert int(g["n_subjects"]) == len(x) == 3
    assert float(g["mean"]) == pytest.approx(x.mean(), rel=1e-12)
    assert float(g["upper"]) - float(g["mean"]) == pytest.approx(h, rel=1e-9)


def test_cache_redoes_only_what_changed(serial, cohort, tmp_path):
    """A rerun takes every finished record from the cache (failures are tried again); a
    changed file redoes its record only; a record whose cache entry is gone (a study
    stopped before it finished) is redone."""
    out0, first = serial
    root, out = tmp_path / "cohort", tmp_path / "study"
    shutil.copytree(cohort, root)
    shutil.copytree(out0, out)
    again = run_study(root / "bad.csv", out)
    assert (again.cached, again.computed, again.failed) == (6, len(BAD) - 1, len(BAD))
    _assert_same_tables(out0, out, tol=0.0, skip=("cached", "reason"))  # reasons name the copy's paths
    # change one file: its record only is identified again
    pt = root / "S04" / "PT.csv"
    lines = pt.read_text().splitlines()
    cells = lines[100].split(",")
    cells[2] = repr(float(cells[2]) + 0.01)
    lines[100] = ",".join(cells)
    pt.write_text("\n".join(lines) + "\n")
    changed = run_study(root / "bad.csv", out)
    assert (changed.cached, changed.computed) == (5, len(BAD))
    assert [r["record"] for r in changed.results if r["status"] == "ok" and not r["cached"]] == ["S04"]


def _entries(folder):
    return sorted(p.name for p in (folder / "cache").glob("*.json") if re.fullmatch(r"[0-9a-f]{24}\.json", p.name))


def test_a_study_killed_halfway_redoes_only_the_unfinished_records(cohort, tmp_path):
    """``lpvpc study`` killed (SIGKILL: no clean-up) after its second record; the rerun takes
    the finished records from the cache and identifies the others only."""
    out = tmp_path / "study"
    cmd = [sys.executable, "-m", "lpvpc.cli", "-q", "study", str(cohort / "manifest.csv"), "-o", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None and len(_entries(out) if out.exists() else []) < 2:
            time.sleep(0.05)
    finally:
        proc.kill()
        proc.wait()
    finished = _entries(out)
    assert 2 <= len(finished) < 6, finished
    assert not (out / "records.csv").exists()  # it did not get to the tables
    resumed = run_study(cohort / "manifest.csv", out)
    assert (resumed.cached, resumed.computed, resumed.failed) == (len(finished), 6 - len(finished), 0)
    assert _entries(out) != finished and len(_entries(out)) == 6


def test_command_line_exit_status_and_summary(serial, cohort, capsys):
    out, _ = serial
    status = main(["-q", "study", str(cohort / "bad.csv"), "-o", str(out)])
    lines = capsys.readouterr().out.splitlines()
    assert status == 1
    assert sum(line.startswith("failed: ") for line in lines) == len(BAD)
    assert any("6 from the cache" in line for line in lines)


def test_process_pool_equals_serial(serial, cohort, tmp_path):
    out, _ = serial
    pooled = run_study(cohort / "bad.csv", tmp_path, jobs=2)
    assert pooled.computed == 5 + len(BAD) and pooled.failed == len(BAD)
    assert len({r["pid"] for r in pooled.results if "pid" in r}) == 2  # two worker processes did the work
    _assert_same_tables(out, tmp_path)


def test_dask_local_cluster_equals_process_pool(serial, cohort, tmp_path):
    distributed = pytest.importorskip("dask.distributed", reason="dask.distributed is not installed "
                                                                 "(pip install 'lpvpc[study]')")
    out, _ = serial
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        result = run_study(cohort / "bad.csv", tmp_path, scheduler=cluster)
    assert result.computed == 5 + len(BAD) and dict(result.failures()).keys() == BAD.keys()
    _assert_same_tables(out, tmp_path)


def test_cohort_truth_and_command_line(tmp_path, capsys):
    import json

    assert main(["-q", "simulate", "--out", str(tmp_path / "c"), "--cohort", "2", "--null", "--duration", "20",
                 "--fs", "100"]) == 0
    truth = json.loads((tmp_path / "c" / "truth.json").read_text())
    assert truth["null"] and max(map(abs, truth["difference"]["stiffness"])) == 0.0
    rows = read_manifest(tmp_path / "c" / "manifest.csv")
    assert [r.group for r in rows] == ["control", "patient"]
    assert main(["-q", "simulate", "--out", str(tmp_path / "d"), "--cohort", "2", "--seed", "3"]) == 2


def test_a_within_subject_design_is_compared_in_pairs(tmp_path):
    """Subjects recorded in both conditions: the difference's interval is the t interval of
    each subject's own difference (not Welch's over two groups), and says so."""
    from scipy import stats

    paths = write_cohort(tmp_path / "within", 3, duration=40.0, fs=100.0, design="within")
    truth = json.loads(paths["truth"].read_text())
    assert truth["design"] == "within" and [r["subject"] for r in truth["records"]] == ["S01", "S01", "S02", "S02",
                                                                                        "S03", "S03"]
    assert len({r["seed"] for r in truth["records"]}) == 6  # each session its own noise
    out = tmp_path / "study"
    run_study(paths["manifest"], out)
    recs = [r for r in _table(out / "records.csv") if r["status"] == "ok"]
    theta = recs[0]["theta"]
    k = {(r["subject"], r["group"]): float(r["stiffness"]) for r in recs if r["theta"] == theta}
    d = np.array([k[(s, "patient")] - k[(s, "control")] for s in ("S01", "S02", "S03")])
    row = next(r for r in _table(out / "groups.csv") if r["quantity"] == "stiffness" and r["theta"] == theta
               and r["group"] == "patient - control")
    assert row["design"] == "paired (3 subjects)" and row["n_subjects"] == "3 pairs"
    assert float(row["mean"]) == pytest.approx(d.mean(), rel=1e-12)
    h = stats.t.ppf(0.975, 2) * d.std(ddof=1) / np.sqrt(3)
    assert float(row["upper"]) - float(row["mean"]) == pytest.approx(h, rel=1e-9)


def test_between_groups_keep_welch(serial):
    out, _ = serial
    diff = [r for r in _table(out / "groups.csv") if r["group"] == "patient - control"]
    assert diff and all(r["design"] == "independent groups (Welch)" for r in diff)


def test_records_are_diagnosed_when_asked(cohort, tmp_path):
    """A row with diagnose true is diagnosed on its held-out part: records.csv names the
    missing effect ("none" when the diagnosis finds none); a held-out part too short for a
    diagnosis keeps its model and says "not diagnosed" with the reason; rows not asked are
    left empty."""
    lines = (cohort / "manifest.csv").read_text().splitlines()
    text = (lines[0] + ",heldout,diagnose\n" + lines[1] + ",0.5,true\n" + lines[2] + ",,\n"
            + lines[3] + ",,true\n")
    manifest = cohort / "diagnose.csv"
    manifest.write_text(text)
    out = tmp_path / "study"
    result = run_study(manifest, out)
    by = {}
    for r in _table(out / "records.csv"):
        by.setdefault(r["record"], set()).add(r["missing_effect"])
    first, second, third = (line.split(",")[0] for line in lines[1:4])
    assert by[second] == {""} and by[third] == {"not diagnosed"}
    assert all(r["status"] == "ok" for r in result.results)
    assert len(by[first]) == 1 and next(iter(by[first])) not in ("", "not diagnosed")
    d = result.results[0]["diagnosis"]
    assert (d["missing"] or "none") == next(iter(by[first])) and d["answer"]
    html = (out / "report.html").read_text()
    assert "missing effect (diagnosis)" in html and "not diagnosed: " in html and "too short" in html


def test_the_study_pieces_by_hand_give_the_study_tables(serial, cohort, tmp_path):
    """The steps run_study takes, called one by one on two records (manifest rows, cache key,
    one job each, the grid, the tables, the report, a record's diagnosis kept as a summary),
    give the tables run_study wrote for those records."""
    from lpvpc.diagnosis import diagnose
    from lpvpc.io import hold_out, load_identification_data
    from lpvpc.study import StudyResult
    from lpvpc.study.manifest import ManifestRow
    from lpvpc.study.report import report_html
    from lpvpc.study.run import analyse_record, diagnosis_summary, execute, record_key
    from lpvpc.study.tables import GROUP_COLUMNS, RECORD_COLUMNS, common_grid, group_rows, records_rows, write_csv

    rows = [r for r in read_manifest(cohort / "manifest.csv")][:2]
    assert all(isinstance(r, ManifestRow) for r in rows)
    settings = {"heldout": 0.3, "identify": {}, "level": 0.95, "grid_step": 0.01, "diagnose": False}
    specs = [{"record": r.record, "key": record_key(r, settings), "pt": r.pt, "ut": r.ut, "heldout": 0.3,
              "level": 0.95} for r in rows]
    results = execute(specs[1:])
    results.insert(0, analyse_record(specs[0]))
    assert [r["status"] for r in results] == ["ok", "ok"]
    grid = common_grid(results)
    write_csv(tmp_path / "records.csv", records_rows(results, rows, grid), RECORD_COLUMNS)
    groups = group_rows(results, rows, grid, [("control", "patient")])
    write_csv(tmp_path / "groups.csv", groups, GROUP_COLUMNS)
    study = _table(serial[0] / "records.csv")
    mine = _table(tmp_path / "records.csv")
    for r in mine:
        same = next(x for x in study if x["record"] == r["record"] and x["theta"] == r["theta"])
        assert float(r["stiffness"]) == float(same["stiffness"]) and r["vaf_heldout"] == same["vaf_heldout"]
    html = report_html(results, rows, grid, groups, [("control", "patient")], counts={"computed": 2})
    assert rows[0].record in html and "<img" in html
    assert isinstance(serial[1], StudyResult) and serial[1].exit_status == 1
    data = load_identification_data(pt=rows[0].pt, ut=rows[0].ut)
    ident, held = hold_out(data, 0.5)
    from lpvpc import identify

    summary = diagnosis_summary(diagnose(identify(ident), held))
    assert set(summary) >= {"missing", "pathway", "significant", "answer"} and summary["answer"]
