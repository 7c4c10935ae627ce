# The two commands a new user runs; each sets itself up on a fresh machine.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test docs bench clean chromium libtbb

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	PATH="$(CURDIR)/$(VENV)/bin:$$PATH" $(PY) -m lpvpc.demo demo_out

# One BLAS thread, as the CLI and demo use: identification's many small least-squares
# problems run faster single-threaded (benchmarks/results/identify.txt). One worker per core
# (pytest-xdist), each test file on one worker so that its module fixtures are built once;
# PYTEST_WORKERS=0 runs the suite in this process.
PYTEST_WORKERS ?= auto
test: $(STAMP) chromium libtbb
	PATH="$(CURDIR)/$(VENV)/bin:$$PATH" OPENBLAS_NUM_THREADS=$${OPENBLAS_NUM_THREADS:-1} \
	  $(PY) -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile

# The documentation, built with warnings as errors (docs/conf.py; the results page is
# generated from benchmarks/results/ at build time). Output: docs/_build/html/index.html.
DOCS_STAMP := $(VENV)/.docs-installed
$(DOCS_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e '.[test,docs]'
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	$(VENV)/bin/sphinx-build -W --keep-going -b html docs docs/_build/html

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do PATH="$(CURDIR)/$(VENV)/bin:$$PATH" OPENBLAS_NUM_THREADS=$${OPENBLAS_NUM_THREADS:-1} $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) demo_out build docs/_build docs/benchmarks.md

# Headless Chromium (Debian's package) for the test that opens the validation report
# (tests/test_validation.py); `make test` depends on it, so a fresh machine gets it. The
# test fails without /usr/bin/chromium unless LPVPC_ALLOW_NO_CHROMIUM is set.
chromium:
	@if [ -x /usr/bin/chromium ]; then echo "chromium: $$(/usr/bin/chromium --version 2>/dev/null)"; else \
	  SUDO=; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y chromium; fi

# Debian's libtbb12, which ECOS (ecospy, a test dependency) needs to load: the portable SSP's
# engine test (tests/test_ssp.py) and tests/test_fmu_engines.py skip ECOS with the reason when
# it is missing.
libtbb:
	@if ldconfig -p 2>/dev/null | grep -q 'libtbb.so.12'; then echo "libtbb12: installed"; else \
	  SUDO=; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y libtbb12; fi
