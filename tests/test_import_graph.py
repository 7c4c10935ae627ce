"""The package's modules import each other without cycles, and its layers point one way.

A cycle makes the import order matter and hides which module a concept belongs to; a layer
that imports a later one (the model importing the diagnosis, say) does the same for whole
subpackages. Both top-level and function-local imports count (``from .x import y``,
``from . import x``, ``from lpvpc.x import y``, ``import lpvpc.x``), read from the source with
ast.
"""

import ast
import importlib
from pathlib import Path

import pytest

#: The layers, each importing only from the layers before it (and from its own). The
#: top-level modules in BASE are what every layer may use (errors, linalg, progress,
#: report_html).
LAYERS = (
    ("lpvpc.io",),
    ("lpvpc.models",),
    ("lpvpc.identification", "lpvpc.simulation"),
    ("lpvpc.export", "lpvpc.plotting"),
    ("lpvpc.diagnosis", "lpvpc.validation"),
    ("lpvpc.study",),  # a study runs identification, validation and diagnosis per record
    ("lpvpc.cli", "lpvpc.demo"),
)
BASE = ("lpvpc._lazy", "lpvpc.errors", "lpvpc.linalg", "lpvpc.progress", "lpvpc.report_html")
#: The only imports against the layers, each a convenience that delegates to a later layer
#: from inside a function (so importing the earlier layer never loads the later one).
ALLOWED_UPWARD = {
    # LPVPCModel.export_fmu / export_casadi: the model's own methods call the exporter
    ("lpvpc.models.model", "lpvpc.export.exporter"),
}


def package_files() -> dict:
    """{module name: source file} of lpvpc and all its subpackages."""
    root = Path(importlib.import_module("lpvpc").__file__).resolve().parent
    files = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        files[name] = path
    return files


def layer_of(module: str):
    """Index of the layer ``module`` belongs to (-1: the base; None: the package itself)."""
    if module == "lpvpc":
        return None
    for prefix in BASE:
        if module == prefix:
            return -1
    for i, layer in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in layer):
            return i
    raise AssertionError(f"{module} belongs to no layer: add it to LAYERS or BASE")


def imported_modules(path: Path, name: str, modules: set) -> set:
    """The package modules ``path`` (module ``name``) imports anywhere in its source."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                target = f"{base}.{node.module}" if node.module else base
            else:
                target = node.module or ""
            # ``from . import x``: the module x (not the package) when x is one; ``from .x import y``: x
            candidates = [f"{target}.{a.name}" if f"{target}.{a.name}" in modules else target
                          for a in node.names]
        elif isinstance(node, ast.Import):
            candidates = [a.name for a in node.names]
        else:
            continue
        found |= {c for c in candidates if c in modules and c != name}
    return found


def import_graph() -> dict:
    paths = package_files()
    # a package's __init__ is imported by its submodules anyway: edges into it are not cycles
    return {name: imported_modules(p, name, set(paths) - {"lpvpc"}) for name, p in paths.items()}


def find_cycle(graph: dict):
    """One cycle as a list of modules [a, b, ..., a], or None."""
    state, stack = {}, []

    def visit(u):
        state[u] = "open"
        stack.append(u)
        for v in sorted(graph.get(u, ())):
            if state.get(v) == "open":
                return stack[stack.index(v):] + [v]
            if v not in state and (cycle := visit(v)):
                return cycle
        stack.pop()
        state[u] = "done"
        return None

    for u in sorted(graph):
        if u not in state and (cycle := visit(u)):
            return cycle
    return None


def test_find_cycle_finds_a_planted_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_graph_sees_function_local_and_absolute_imports(tmp_path):
    source = tmp_path / "mod.py"
    source.write_text("from . import equations as eq\nimport lpvpc.models.basis\n"
                      "def f():\n    from .model import vaf\n    from lpvpc.io import Trial\n")
    modules = {"lpvpc.models.equations", "lpvpc.models.basis", "lpvpc.models.model", "lpvpc.io",
               "lpvpc.models.mod"}
    assert imported_modules(source, "lpvpc.models.mod", modules) == modules - {"lpvpc.models.mod"}


def test_package_import_graph_has_no_cycles():
    graph = import_graph()
    assert "lpvpc.models.uncertainty" in graph["lpvpc.identification.identify"]  # the graph is read (sanity),
    assert "lpvpc.validation.closed_loop" in graph["lpvpc.demo"]  # with the subpackages
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def upward_imports(graph: dict) -> set:
    """(importer, imported) pairs where a module imports from a later layer, or from another
    subpackage of its own layer."""
    found = set()
    for module, targets in graph.items():
        here = layer_of(module)
        if here is None:
            continue
        for target in targets:
            there = layer_of(target)
            if there is None or there < here:
                continue
            same_layer_other_package = there == here and here >= 0 and not any(
                module.startswith(p) and target.startswith(p) for p in LAYERS[here])
            if there > here or same_layer_other_package:
                found.add((module, target))
    return found


def test_layers_point_one_way():
    upward = upward_imports(import_graph())
    assert upward <= ALLOWED_UPWARD, "imports against the layers: " + ", ".join(
        f"{a} -> {b}" for a, b in sorted(upward - ALLOWED_UPWARD))
    assert upward == ALLOWED_UPWARD, f"no longer needed in ALLOWED_UPWARD: {ALLOWED_UPWARD - upward}"


def test_layer_check_finds_a_planted_upward_import():
    graph = {"lpvpc.io.trial": {"lpvpc.models.model"}, "lpvpc.models.model": {"lpvpc.io.trial"},
             "lpvpc.identification.identify": {"lpvpc.simulation.simulate"}}
    assert upward_imports(graph) == {("lpvpc.io.trial", "lpvpc.models.model"),
                                     ("lpvpc.identification.identify", "lpvpc.simulation.simulate")}


@pytest.mark.parametrize("name", ["identify", "diagnose", "improve"])
def test_entry_modules_are_one_object_under_both_names(name):
    import lpvpc

    module = importlib.import_module(f"lpvpc.{name}")
    assert module is getattr(lpvpc, name) and callable(module)
    assert module is importlib.import_module(lpvpc._ENTRY_MODULES[name])


@pytest.mark.parametrize("package", ["lpvpc.io", "lpvpc.models", "lpvpc.simulation", "lpvpc.export"])
def test_subpackage_re_exports_resolve(package):
    """Each name a subpackage lists in ``__all__`` loads from the module it names."""
    module = importlib.import_module(package)
    assert module.__all__
    for name in module.__all__:
        assert getattr(module, name) is not None, f"{package}.{name}"


def test_the_export_package_re_exports_the_exporters_public_names():
    import lpvpc.export
    import lpvpc.export.exporter

    assert sorted(lpvpc.export.__all__) == sorted(lpvpc.export.exporter.__all__)
