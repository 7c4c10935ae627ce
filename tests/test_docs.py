"""The README is a newcomer's guide: short, with an install command and the two set-up
commands, links that reach the user guide, and a Python quick start that runs as written.
(The Sphinx build itself is checked by `make docs` in CI; this file does not need Sphinx.)
"""

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from lpvpc.simulation.simulate import write_dataset

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
MAX_README_LINES = 250


def _readme() -> str:
    return README.read_text(encoding="utf-8")


def test_readme_is_short_and_says_how_to_install():
    text = _readme()
    lines = text.splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines (at most {MAX_README_LINES})"
    assert re.search(r"^\S*pip install \S+", text, re.M), "README.md has no pip install command"
    # the two commands that set themselves up on a fresh machine; CI runs the test one
    assert "make demo" in lines and "make test" in lines
    assert "make test" in (REPO / ".ci" / "run").read_text().splitlines()


def test_readme_has_no_internal_references():
    text = _readme()
    for pattern in (r"\.\./shared", r"\bissue\b", r"benchmarks/results/\w+\.txt", r"\bfloor\b"):
        assert not re.search(pattern, text, re.I), f"README.md mentions {pattern!r}"


def test_readme_links_reach_existing_pages():
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", _readme())
    local = [link for link in links if not re.match(r"[a-z]+://", link)]
    assert any(link.startswith("docs/guide/") for link in local), "README.md links to no guide page"
    missing = [link for link in local if not (REPO / link).is_file()]
    assert not missing, f"README.md links to missing files: {missing}"


def test_guide_pages_start_with_a_title():
    pages = sorted((REPO / "docs" / "guide").glob("*.md"))
    assert pages
    for page in pages:
        first = page.read_text(encoding="utf-8").lstrip().splitlines()[0]
        assert re.match(r"# \S", first), f"{page.name} does not start with a '# Title' heading"


@pytest.mark.slow
def test_readme_python_quick_start_runs(tmp_path, monkeypatch):
    """The README's Python block, verbatim, on the virtual subject that `lpvpc simulate
    --out subject` writes: it predicts the novel trajectory well and writes what it says."""
    block = re.search(r"## Quick start: Python\n+```python\n(.*?)```", _readme(), re.S)
    assert block, "README.md has no Python quick start"
    write_dataset(tmp_path / "subject", seed=0)
    monkeypatch.chdir(tmp_path)
    env: dict = {}
    with warnings.catch_warnings():  # the novel trajectory leaves the identified range a little
        warnings.simplefilter("ignore")
        exec(compile(block.group(1), "README.md:quick-start", "exec"), env)
    assert env["vaf"](env["test"].torque, env["pred"].total) > 95.0
    k = np.asarray(env["model"].elastic_stiffness([-0.3, 0.0, 0.15]))
    assert np.all(k > 0) and k[2] > k[1]  # stiffer toward dorsiflexion
    assert np.all(np.asarray(env["lo"]) < k) and np.all(k < np.asarray(env["hi"]))
    for name in ("model.json", "model.fmu", "model.casadi"):
        assert (tmp_path / name).stat().st_size > 0, name
