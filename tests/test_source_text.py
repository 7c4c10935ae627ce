"""The package's code says why in a line; evidence and history live in the documentation.

Comments and docstrings under lpvpc/ carry no issue numbers and no anecdotes of particular
random seeds (those go to docs/design_notes.md or benchmarks/results/), and the design-notes
sections the code points at exist.
"""

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "lpvpc"
DESIGN_NOTES = REPO / "docs" / "design_notes.md"
SOURCE_SUFFIXES = {".py", ".c", ".h", ".md", ".txt", ".toml", ".json", ".html", ".js", ".css"}

#: an issue or pull-request number: "issue 37", "issue-23", "Issue #5", "PR #12", "gh-40", "#37"
#: (a '#' followed by digits, not a CSS colour such as "#222;" or "color:#176b1a")
ISSUE = re.compile(r"\bissues?[\s-]*#?\d+|\b(?:PR|pull request)(?:\s*#|\s+)\d+|\bgh-\d+|(?<![\w:&#])#\d{1,5}\b(?![\w;])",
                   re.IGNORECASE)
#: an anecdote of particular random seeds in prose: "seed 8", "seeds 0-19", "a seed (45)"
SEED_ANECDOTE = re.compile(r"\bseeds?\s*[-(]?\s*\d+", re.IGNORECASE)

#: Files another change is rewriting now; their seed anecdotes move to docs/design_notes.md with
#: that change, and each entry is removed then (the test fails on an entry that is clean).
SEED_ANECDOTES_PENDING: set = set()


def _sources():
    return sorted(p for p in PACKAGE.rglob("*") if p.is_file() and p.suffix in SOURCE_SUFFIXES
                  and "__pycache__" not in p.parts)


def _hits(pattern, path):
    text = path.read_text(encoding="utf-8", errors="replace")
    return [f"{path.relative_to(REPO)}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)!r}"
            for m in pattern.finditer(text)]


def test_the_patterns_catch_what_they_are_for():
    for text in ("see issue 37", "(issue-23 subject)", "Issue #5", "PR #12", "fixed in #37.", "gh-40"):
        assert ISSUE.search(text), text
    for text in ("color:#222;", "#176b1a", "x = y  # 2 samples", "the 1e-6 issue of rounding", "issues a warning",
                 "pr0 = pr[0]"):
        assert not ISSUE.search(text), text
    for text in ("virtual subject, seed 8:", "seeds 0-19 of 1 kHz files", "seed-3 record", "one clean seed (45)"):
        assert SEED_ANECDOTE.search(text), text
    for text in ("seed=0", "seed : int, default 0", "the seed of the generator"):
        assert not SEED_ANECDOTE.search(text), text


def test_no_issue_numbers_in_the_package():
    hits = [h for p in _sources() for h in _hits(ISSUE, p)]
    assert not hits, "issue numbers in the package (say why in the code; history goes to docs/):\n" + "\n".join(hits)


def test_no_seed_anecdotes_in_the_package():
    hits = [h for p in _sources() if str(p.relative_to(REPO)) not in SEED_ANECDOTES_PENDING
            for h in _hits(SEED_ANECDOTE, p)]
    assert not hits, ("seed anecdotes in the package (move the evidence to docs/design_notes.md and keep a "
                      "one-line why):\n" + "\n".join(hits))


@pytest.mark.parametrize("pending", sorted(SEED_ANECDOTES_PENDING))
def test_pending_seed_anecdotes_are_still_pending(pending):
    path = REPO / pending
    if not path.exists():
        pytest.fail(f"{pending} is gone: remove it from SEED_ANECDOTES_PENDING")
    assert _hits(SEED_ANECDOTE, path), f"{pending} is clean now: remove it from SEED_ANECDOTES_PENDING"


def test_design_notes_sections_the_code_cites_exist():
    headings = [line[3:].strip() for line in DESIGN_NOTES.read_text(encoding="utf-8").splitlines()
                if line.startswith("## ")]
    cited = []
    for path in _sources():
        text = path.read_text(encoding="utf-8", errors="replace")
        for m in re.finditer(r'design_notes\.md,\s*(?:#:?\s*)?"([^"]+)"', text):
            cited.append((path, re.sub(r"\s*\n\s*(?:#:?)?\s*", " ", m.group(1))))
    assert cited, "no citation of docs/design_notes.md found (the pattern is stale)"
    missing = [f"{p.relative_to(REPO)}: {name!r}" for p, name in cited if not any(h.startswith(name) for h in headings)]
    assert not missing, "design-notes sections cited but absent:\n" + "\n".join(missing)
