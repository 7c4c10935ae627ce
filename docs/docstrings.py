"""Read lpvpc's plain-text docstrings as reStructuredText without editing them.

The docstrings are written for ``help()``: ASCII formulas such as ``|v|`` and displays
introduced by a colon. Before napoleon sees them (priority < 500) this hook
- escapes ``|`` outside inline literals (rST would take ``|v|`` for a substitution);
- turns a paragraph ending in ``:`` followed by a blank line and an indented block into
  a literal block (``::``), so formulas keep their layout;
- escapes a ``*`` that starts a continuation line (a formula wrapped at an operator),
  which rST would take for a bullet without a blank line before it;
- in a numpy-style parameter section, reads ``name : a description in words`` as a
  name and its description (lpvpc writes descriptions there, not types), so napoleon does
  not take the description for a type;
- in module docstrings, renames a "Parameters" heading (there a narrative section, not a
  function's parameter list) so napoleon leaves it alone.
"""

import re

NARRATIVE_HEADINGS = {"parameters": "The parameters"}
PARAMETER_HEADINGS = ("parameters", "parameters (defaults suit 100 hz ankle data)", "other parameters")
DESCRIBED = re.compile(r"^(\s*)([A-Za-z_][\w, ]*?) : (\S+(?: \S+){3,}.*)$")  # 4+ words: a description


def _escape_pipes(line: str) -> str:
    parts = line.split("``")
    for i in range(0, len(parts), 2):  # even parts are outside ``inline literals``
        parts[i] = re.sub(r"(?<!\\)\|", r"\\|", parts[i])
    return "``".join(parts)


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def prepare(app, what, name, obj, options, lines):
    out = [_escape_pipes(s) for s in lines]
    for i in range(1, len(out)):  # "* fs)" continuing a formula is not a bullet
        prev, s = out[i - 1].strip(), out[i].lstrip()
        if s.startswith("* ") and prev and not prev.startswith("* ") and prev[-1] not in ".:;":
            out[i] = out[i].replace("*", "\\*", 1)
    for i, s in enumerate(out):
        if not (s.rstrip().endswith(":") and not s.rstrip().endswith("::")):
            continue
        if i + 2 < len(out) and not out[i + 1].strip() and out[i + 2].strip() \
                and _indent(out[i + 2]) > _indent(s):
            out[i] = s.rstrip() + ":"
    section, base = False, 0
    described = []
    for i, s in enumerate(out):
        if i + 1 < len(out) and s.strip().lower() in PARAMETER_HEADINGS and re.fullmatch(r"-{3,}", out[i + 1].strip()):
            section, base = True, _indent(s)
        elif section and s.strip() and _indent(s) <= base and re.fullmatch(r"-{3,}", (out[i + 1] if i + 1 < len(out) else "").strip()):
            section = False  # the next section's heading
        m = DESCRIBED.match(s) if section and _indent(s) == base else None
        if m:
            described += [m.group(1) + m.group(2), m.group(1) + "    " + m.group(3)]
        else:
            described.append(s)
    out = described
    if what == "module":
        for i in range(len(out) - 1):
            key = out[i].strip().lower()
            if key in NARRATIVE_HEADINGS and re.fullmatch(r"-{3,}", out[i + 1].strip()):
                out[i] = NARRATIVE_HEADINGS[key]
                out[i + 1] = "-" * len(out[i])
    lines[:] = out


def setup(app):
    app.connect("autodoc-process-docstring", prepare, priority=400)
    return {"parallel_read_safe": True}
