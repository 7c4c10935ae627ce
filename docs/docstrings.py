"""Read lpvpc's plain-text docstrings as reStructuredText without editing them.

The docstrings are written for ``help()``: ASCII formulas such as ``|v|`` and displays
introduced by a colon. Before napoleon sees them (priority < 500) this hook
- escapes ``|`` outside inline literals (rST would take ``|v|`` for a substitution);
- turns a paragraph ending in ``:`` followed by a blank line and an indented block into
  a literal block (``::``), so formulas keep their layout;
- escapes a ``*`` that starts a continuation line (a formula wrapped at an operator),
  which rST would take for a bullet without a blank line before it;
- in a numpy-style parameter section, reads ``name : a description in words`` as a
  name and its description (older lpvpc docstrings write descriptions there, not types), so
  napoleon does not take the description for a type; a line that states ``, default ...`` or
  ends in ``, optional`` is a numpydoc type and is left alone;
- in the docstring of an attribute or constant (a ``#:`` comment), keeps napoleon from reading
  the words before the first colon ("s: the shortest part ...") as the attribute's type;
- in module docstrings, renames a "Parameters" heading (there a narrative section, not a
  function's parameter list) so napoleon leaves it alone.
"""

import re

NARRATIVE_HEADINGS = {"parameters": "The parameters"}
PARAMETER_HEADINGS = ("parameters", "parameters (defaults suit 100 hz ankle data)", "other parameters")
DESCRIBED = re.compile(r"^(\s*)([A-Za-z_][\w, ]*?) : (\S+(?: \S+){3,}.*)$")  # 4+ words: a description
NUMPYDOC_TYPE = re.compile(r",\s*(default\b|optional\s*$)")  # ... unless it states a default


def _escape_pipes(line: str) -> str:
    parts = line.split("``")
    for i in range(0, len(parts), 2):  # even parts are outside ``inline literals``
        parts[i] = re.sub(r"(?<!\\)\|", r"\\|", parts[i])
    return "``".join(parts)


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def _escape_continued_products(lines):
    """A line starting with "* " right after a line of text continues a formula."""
    out = list(lines)
    for i in range(1, len(out)):
        prev, s = out[i - 1].strip(), out[i].lstrip()
        if s.startswith("* ") and prev and not prev.startswith("* ") and prev[-1] not in ".:;":
            out[i] = out[i].replace("*", "\\*", 1)
    return out


def _literal_displays(lines):
    """A line ending in a single ':', then a blank line, then a deeper indented block."""
    out = list(lines)
    for i, s in enumerate(out[:-2]):
        text = s.rstrip()
        if text.endswith(":") and not text.endswith("::") and not out[i + 1].strip() \
                and out[i + 2].strip() and _indent(out[i + 2]) > _indent(s):
            out[i] = text + ":"
    return out


def _is_underline(line) -> bool:
    return re.fullmatch(r"-{3,}", line.strip()) is not None


def _described_parameters(lines):
    """'name : words words words words' in a parameter section -> name, indented words."""
    out, section, base = [], False, 0
    for i, s in enumerate(lines):
        underlined = i + 1 < len(lines) and _is_underline(lines[i + 1])
        if underlined and s.strip().lower() in PARAMETER_HEADINGS:
            section, base = True, _indent(s)
        elif underlined and section and s.strip() and _indent(s) <= base:
            section = False  # the next section's heading
        m = DESCRIBED.match(s) if section and _indent(s) == base else None
        if m and NUMPYDOC_TYPE.search(m.group(3)):
            m = None  # "name : type, default value": a numpydoc type, left to napoleon
        out += [m.group(1) + m.group(2), m.group(1) + "    " + m.group(3)] if m else [s]
    return out


def _narrative_headings(lines):
    out = list(lines)
    for i in range(len(out) - 1):
        key = out[i].strip().lower()
        if key in NARRATIVE_HEADINGS and _is_underline(out[i + 1]):
            out[i] = NARRATIVE_HEADINGS[key]
            out[i + 1] = "-" * len(out[i])
    return out


def _no_inline_type(lines):
    """napoleon reads "words: more words" on an attribute's first line as "type: description";
    lpvpc's attribute comments start with a unit or a phrase, never a type. An empty rST
    comment as the first line leaves napoleon nothing to read as the type (it renders as
    nothing; napoleon skips blank lines, so a blank line would not do)."""
    first = re.sub(r"``.*?``|`.*?`", "", lines[0]) if lines else ""
    return ["..", ""] + list(lines) if re.search(r"(?<!:):(?!:)", first) else list(lines)


def prepare(app, what, name, obj, options, lines):
    out = [_escape_pipes(s) for s in lines]
    out = _described_parameters(_literal_displays(_escape_continued_products(out)))
    if what == "module":
        out = _narrative_headings(out)
    if what in ("attribute", "data", "property"):
        out = _no_inline_type(out)
    lines[:] = out


def setup(app):
    app.connect("autodoc-process-docstring", prepare, priority=400)
    return {"parallel_read_safe": True}
