"""Sphinx configuration of the lpvpc documentation (`make docs` builds it with -W)."""

import logging
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the local extension below

import lpvpc  # noqa: E402  (installed in the project venv by `make docs`)

project = "lpvpc"
author = "lpvpc contributors"
release = version = lpvpc.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "docstrings",  # reads the plain-text docstrings as rST (see docstrings.py)
    "results_page",  # writes benchmarks.md from benchmarks/results/*.txt before reading
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build"]
myst_enable_extensions = ["colon_fence", "dollarmath"]
myst_heading_anchors = 3

autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
napoleon_google_docstring = True
napoleon_numpy_docstring = True
# LPVPCEstimator's parameter section carries a note in its heading
napoleon_custom_sections = [("Parameters (defaults suit 100 Hz ankle data)", "params_style")]
# Types in parameter sections are read as types: "optional", "default 5" and {"a", "b"} become
# text and literals, and the short names below point where Sphinx can find them.
napoleon_preprocess_types = True
napoleon_type_aliases = {
    "array_like": "numpy.typing.ArrayLike",
    "array-like": "numpy.typing.ArrayLike",
    "callable": "collections.abc.Callable",
}

# Every cross-reference must resolve (-W makes a broken one an error). The build runs without
# internet, hence without intersphinx: names from other packages are listed here, and only
# those; a reference to an lpvpc name must point at a documented object.
nitpicky = True
nitpick_ignore_regex = [
    (r"py:.*", r"(numpy|np|scipy|casadi|matplotlib|pandas|fmpy|dask)(\..*)?"),
    (r"py:obj", r"True|False|None"),
    (r"py:class", r"Path|ndarray|'numpy\.ndarray'|'pathlib\.Path'"),  # pathlib.Path, numpy.ndarray
    (r"py:.*", r"(pathlib|os|collections\.abc|typing|types|io|enum|dataclasses|concurrent)\..*"),
]

html_theme = "furo"
html_title = f"lpvpc {release}"


def _not_empty_glob(record) -> bool:
    return getattr(record, "subtype", None) != "empty_glob"


def setup(app):
    # The guide's toctree lists its pages in reading order, then `guide/*` for pages added
    # later; while every page is listed that glob matches nothing, which is not an error.
    # (suppress_warnings cannot name it: Sphinx gives this warning no type.)
    logging.getLogger("sphinx.sphinx.directives.other").addFilter(_not_empty_glob)
