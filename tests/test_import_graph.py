"""The package's modules import each other without cycles (issue 25 item 7): a cycle makes
the import order matter and hides which module a concept belongs to. Both top-level and
function-local imports count (``from .x import y``, ``from . import x``, ``from lpvpc.x
import y``, ``import lpvpc.x``), read from the source with ast."""

import ast
import importlib
from pathlib import Path

#: subpackages with Python modules (installed from their own folders, see pyproject.toml)
SUBPACKAGES = ("lpvpc.validation",)


def package_files() -> dict:
    """{module name: source file} of lpvpc and of its subpackages, wherever they live
    (lpvpc.validation is the repository's validation/ folder)."""
    files = {}
    for package in ("lpvpc", *SUBPACKAGES):
        module = importlib.import_module(package)
        folder = Path(module.__file__).resolve().parent
        for path in folder.glob("*.py"):
            name = module.__name__ if path.stem == "__init__" else f"{module.__name__}.{path.stem}"
            files[name] = path
    return files


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
    source.write_text("from . import equations as eq\nimport lpvpc.basis\n"
                      "def f():\n    from .model import vaf\n    from lpvpc.data import Trial\n")
    modules = {"lpvpc.equations", "lpvpc.basis", "lpvpc.model", "lpvpc.data", "lpvpc.mod"}
    assert imported_modules(source, "lpvpc.mod", modules) == modules - {"lpvpc.mod"}


def test_package_import_graph_has_no_cycles():
    graph = import_graph()
    assert "lpvpc.uncertainty" in graph["lpvpc.identify"]  # the graph is read (sanity),
    assert "lpvpc.validation.closed_loop" in graph["lpvpc.demo"]  # with the subpackages
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)
