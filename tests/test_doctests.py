"""The main entry points' docstrings are numpydoc (Parameters, Returns, Raises, Examples) and
their examples run, fast, as doctests.

pytest's ``--doctest-modules`` (pyproject.toml) runs every example in lpvpc already; this file
states which docstrings must have one and what shape they must have, and runs those examples
itself, each within a time budget, so that a missing or slow example fails here by name.
The public names (``lpvpc.__all__`` and the subpackages' ``__all__``) must have the numpydoc
sections too; ``SECTIONS_PENDING`` lists those still without them (it may only shrink).
"""

import doctest
import importlib
import inspect
import re
import time

import pytest

import lpvpc

#: the entry points a user starts from: name -> (module, qualified name in it)
ENTRY_POINTS = {
    "identify": ("lpvpc.identification.identify", "identify"),
    "LPVPCEstimator": ("lpvpc.identification.identify", "LPVPCEstimator"),
    "LPVPCEstimator.fit": ("lpvpc.identification.identify", "LPVPCEstimator.fit"),
    "LPVPCModel.predict": ("lpvpc.models.model", "LPVPCModel.predict"),
    "LPVPCModel.summary": ("lpvpc.models.model", "LPVPCModel.summary"),
    "LPVPCModel.export_fmu": ("lpvpc.models.model", "LPVPCModel.export_fmu"),
    "LPVPCModel.export_casadi": ("lpvpc.models.model", "LPVPCModel.export_casadi"),
    "load_identification_data": ("lpvpc.io.identification_data", "load_identification_data"),
    "hold_out": ("lpvpc.io.identification_data", "hold_out"),
    "simulate_pair": ("lpvpc.simulation.simulate", "simulate_pair"),
    "write_dataset": ("lpvpc.simulation.simulate", "write_dataset"),
    "diagnose": ("lpvpc.diagnosis.diagnose", "diagnose"),
    "validate": ("lpvpc.validation.harness", "validate"),
    "improve": ("lpvpc.diagnosis.improve", "improve"),
}
#: entry points whose module another change is rewriting now: their sections come with it
#: (the test fails once one has them, so that the entry moves to ENTRY_POINTS)
ENTRY_POINTS_PENDING: dict = {}
#: s: an example of an entry point runs within this (each takes 0.1-3 s alone on a laptop core;
#: the budget leaves room for a loaded machine, not for an example that fits a long record)
EXAMPLE_BUDGET_S = 30.0

#: public names (lpvpc.__all__, then "subpackage.name") whose docstrings still lack numpydoc
#: sections (Ladder and improve: their module is being rewritten by another change)
SECTIONS_PENDING: set = set()

SECTION = re.compile(r"^[ \t]*([A-Z][A-Za-z ]*)\n[ \t]*-{3,}[ \t]*$", re.M)


def _resolve(module: str, qualname: str):
    obj = __import__(module, fromlist=["_"])
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def sections(obj) -> set:
    """The numpydoc section headings of ``obj``'s docstring (a class's Attributes count as its
    Parameters: a dataclass's fields are both)."""
    found = set(SECTION.findall(inspect.getdoc(obj) or ""))
    if inspect.isclass(obj) and "Attributes" in found:
        found.add("Parameters")
    return found


def required_sections(obj) -> set:
    """Parameters when it takes any; Returns for a function not annotated ``-> None``; Raises
    when its own body raises; Examples always."""
    need = {"Examples"}
    target = obj.__init__ if inspect.isclass(obj) else obj
    try:
        params = [p for p in inspect.signature(target).parameters if p not in ("self", "cls")]
    except (TypeError, ValueError):
        params = []
    if params:
        need.add("Parameters")
    if not inspect.isclass(obj):
        try:
            returns_none = inspect.signature(obj).return_annotation in (None, "None")
        except (TypeError, ValueError):
            returns_none = False
        if not returns_none:
            need.add("Returns")
        try:
            body = inspect.getsource(obj)
        except (OSError, TypeError):
            body = ""
        if re.search(r"^\s+raise \w", body, re.M):
            need.add("Raises")
    return need


@pytest.mark.parametrize("name", sorted(ENTRY_POINTS))
def test_entry_point_docstring_has_numpydoc_sections(name):
    obj = _resolve(*ENTRY_POINTS[name])
    missing = required_sections(obj) - sections(obj)
    assert not missing, f"{name}: its docstring lacks the numpydoc section(s) {sorted(missing)}"
    assert ">>>" in (obj.__doc__ or ""), f"{name}: its Examples section has no '>>>' example"


@pytest.mark.parametrize("name", sorted(ENTRY_POINTS_PENDING))
def test_pending_entry_points_are_still_pending(name):
    obj = _resolve(*ENTRY_POINTS_PENDING[name])
    if not required_sections(obj) - sections(obj):
        pytest.fail(f"{name} has its numpydoc sections now: move it to ENTRY_POINTS")


@pytest.mark.parametrize("name", sorted(ENTRY_POINTS))
def test_entry_point_examples_run_fast(name):
    module, qualname = ENTRY_POINTS[name]
    obj = _resolve(module, qualname)
    mod = __import__(module, fromlist=["_"])
    tests = [t for t in doctest.DocTestFinder(recurse=False).find(obj, name, module=mod, globs=vars(mod))
             if t.examples]
    assert tests, f"{name}: no doctest found"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    t0 = time.perf_counter()
    for test in tests:
        runner.run(test)
    elapsed = time.perf_counter() - t0
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed (output above)"
    assert elapsed < EXAMPLE_BUDGET_S, f"{name}: its examples took {elapsed:.1f} s (budget {EXAMPLE_BUDGET_S} s)"


SUBPACKAGES = ("io", "models", "identification", "simulation", "export", "diagnosis", "validation", "study")


def _top_level():
    """{name: object} of the public functions and classes: ``lpvpc.__all__`` by their top-level
    name, then each subpackage's ``__all__`` as ``subpackage.name`` (names exported at the top
    level too are checked once, there)."""
    out, seen = {}, set()

    def add(key, obj):
        if (inspect.isfunction(obj) or inspect.isclass(obj)) and id(obj) not in seen and not (
                inspect.isclass(obj) and issubclass(obj, (BaseException, Warning))):
            out[key] = obj
            seen.add(id(obj))

    for name in lpvpc.__all__:
        obj = getattr(lpvpc, name)
        add(name, getattr(obj, name) if inspect.ismodule(obj) else obj)  # identify, diagnose, improve
    for sub in SUBPACKAGES:
        module = importlib.import_module(f"lpvpc.{sub}")
        for name in getattr(module, "__all__", ()):
            add(f"{sub}.{name}", getattr(module, name))
    return out


def test_top_level_names_have_numpydoc_sections():
    missing = {name: sorted(required_sections(obj) - {"Examples"} - sections(obj))
               for name, obj in _top_level().items() if name not in SECTIONS_PENDING}
    missing = {k: v for k, v in missing.items() if v}
    assert not missing, f"public names whose docstrings lack numpydoc sections: {missing}"


def test_sections_pending_only_shrinks():
    top = _top_level()
    done = sorted(n for n in SECTIONS_PENDING
                  if n not in top or not (required_sections(top[n]) - {"Examples"} - sections(top[n])))
    assert not done, f"remove from SECTIONS_PENDING (gone, or has its sections now): {', '.join(done)}"
