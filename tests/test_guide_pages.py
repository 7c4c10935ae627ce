"""The guide pages as a reader copies from them: flags in code spans (Markdown turns a bare
``--ut`` into an en dash), code blocks that fit the page, one statement of what a model does
beyond its identified range, and identify's help on the defaults the selection overrides."""

import re
from pathlib import Path

import pytest

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "guide"
PAGES = sorted(GUIDE.glob("*.md"))
MAX_CODE_LINE = 100  # characters: wider lines are cut at the right edge of the rendered page


def _prose(text):
    """The page with fenced and indented code blanked (line numbers kept)."""
    out, fenced, prev_blank = [], False, True
    for line in text.splitlines():
        if line.strip().startswith(("```", "~~~")):
            fenced = not fenced
            out.append("")
            continue
        indented = line.startswith("    ") and prev_blank and not line.lstrip().startswith(("- ", "* ", "|"))
        if fenced or indented:
            out.append("")
            continue
        prev_blank = not line.strip()
        out.append(line)
    return "\n".join(out)


def _code_lines(text):
    fenced = False
    for i, line in enumerate(text.splitlines(), 1):
        if line.strip().startswith(("```", "~~~")):
            fenced = not fenced
        elif fenced:
            yield i, line


def test_pages_found():
    assert len(PAGES) >= 10


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_flags_in_prose_are_code(page):
    """Outside code, a flag becomes an en dash and cannot be copied: every --flag in code."""
    text = re.sub(r"`[^`]*`", lambda m: " " * len(m.group(0)), _prose(page.read_text()), flags=re.S)
    bare = [text.count("\n", 0, m.start()) + 1 for m in re.finditer(r"(?<![\w-])--[A-Za-z]", text)]
    assert not bare, f"{page.name}: a flag outside a code span on line(s) {bare}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_code_blocks_fit(page):
    long = [(i, len(line)) for i, line in _code_lines(page.read_text()) if len(line) > MAX_CODE_LINE]
    assert not long, f"{page.name}: code lines over {MAX_CODE_LINE} characters (line, length): {long}"


def test_one_statement_of_what_happens_beyond_the_range():
    """identification.md states the rule (it depends on the model: clip or linear); no other
    page states one rule for every model, and those that speak of it link to the statement."""
    home = (GUIDE / "identification.md").read_text()
    assert "## Beyond the identified range" in home and "`clip`" in home and "`linear`" in home
    for page in PAGES:
        if page.name == "identification.md":
            continue
        prose = _prose(page.read_text())
        assert not re.search(r"model is held at its boundary|is held at the boundary there", prose), page.name
        if re.search(r"outside the\s+identified range|beyond the identified range", prose, re.I) and \
                page.name in ("command_line.md", "common-mistakes.md"):
            assert "identification.md#beyond-the-identified-range" in prose, page.name


def test_identify_help_says_when_the_selection_overrides_a_default(capsys):
    from lpvpc.cli import build_parser
    from lpvpc.identification.selection import SEARCH

    with pytest.raises(SystemExit):
        build_parser().parse_args(["identify", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    text = text[text.index("positional arguments"):]  # the option descriptions, not the usage line
    order = re.search(r"--intrinsic-order N (.*?) --reflex-order", text).group(1)
    assert "--structure fixed" in order and "cross-validation" in order and "unless given" in order
    lo, hi = min(SEARCH["intrinsic_order"]), max(SEARCH["intrinsic_order"])
    assert f"among {lo} to {hi}" in order
    assert "default: chosen by the structure selection" in text  # --extrapolation
