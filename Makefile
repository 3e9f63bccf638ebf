# Two commands: `make demo` and `make test` (and `make docs` for the documentation site). Each sets everything up first (idempotent):
# Debian's SuiteSparse headers (for the optional scikit-sparse / CHOLMOD extra), a virtual env in
# .venv, and the package with its test, notebook and cholmod extras. `pip install fgopt` alone
# needs no apt and no compiler (wheels only); CHOLMOD is then simply not used.

VENV    := .venv
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.fgopt-installed
SUDO    := $(shell [ "$$(id -u)" = "0" ] || echo sudo)
export FGOPT_DATA ?= $(abspath ../shared/data)
# CHOLMOD's supernodal factorization runs on the system BLAS: Debian's default is the reference
# BLAS; OpenBLAS makes it 3-4x faster on 3D pose graphs (measured on sphere2500).
APT_PACKAGES := libsuitesparse-dev libopenblas0-pthread

DOCS_STAMP := $(VENV)/.fgopt-docs-installed
# The extras `make setup` installs; .ci/run adds `docs` so that `make docs` after `make test`
# needs no second pip run (pip >= 21.3 installs the editable package; setuptools and wheel come
# from the build's isolated environment, so the venv's own need no upgrade).
# --no-compile: pip byte-compiles none of the ~9,200 installed modules (46 s of CPU, one
# core, measured under load); Python compiles the few hundred a process imports on first import.
EXTRAS ?= test,notebook,distributed,cholmod

.PHONY: setup demo test test-no-cholmod bench docs clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	@if ! dpkg -s $(APT_PACKAGES) >/dev/null 2>&1; then \
	  echo "==> installing $(APT_PACKAGES) (CHOLMOD for scikit-sparse, OpenBLAS for CHOLMOD)"; \
	  $(SUDO) apt-get install -y -q $(APT_PACKAGES) >/dev/null 2>&1 || \
	  { $(SUDO) apt-get update -q >/dev/null && $(SUDO) apt-get install -y -q $(APT_PACKAGES) >/dev/null; }; \
	fi
	@test -x $(PY) || { echo "==> creating $(VENV)"; python3 -m venv $(VENV); }
	@echo "==> installing fgopt and its dependencies into $(VENV)"
	@$(PY) -c 'import pip, sys; sys.exit(tuple(map(int, pip.__version__.split(".")[:2])) < (21, 3))' || \
	  $(PY) -m pip install -q --disable-pip-version-check --upgrade pip
	@$(PY) -m pip install -q --disable-pip-version-check --no-compile -e '.[$(EXTRAS)]'
	@touch $(STAMP)

# The built-in families' machine code is compiled once per machine (~2 min on 2 idle cores; seconds
# when cached), so the demo and a user's first scripts load it instead of compiling it.
demo: setup
	@$(PY) -m fgopt.cli cache build
	@$(PY) -m fgopt.demo

# One worker per core (at most 4), a test file per worker: 10.5 min instead of 17.7 on 2 cores
# with empty caches (numba compiles dominate and run single-threaded). tests/conftest.py starts
# the few long files first (LONG_FIRST) and hands out the notebooks one by one.
test: setup
	@$(PY) -m pytest -q -n auto --maxprocesses 4 --dist loadfile

# The same suite as if the CHOLMOD extra (scikit-sparse) were not installed (tests/conftest.py):
# the fallback solvers and orderings, and the skips of CHOLMOD-only tests.
test-no-cholmod: setup
	@FGOPT_HIDE_EXTRAS=sksparse $(PY) -m pytest -q -n auto --maxprocesses 4 --dist loadfile

# Regenerates every README table at HEAD (~75 min on 2 cores); `make bench SKIP=scale,gnc`
# for a shorter run (skipped tables keep their saved results and say so).
bench: setup
	@$(PY) -m pip install -q --disable-pip-version-check -e '.[bench]'
	@$(PY) -m benchmarks.run --all $(if $(SKIP),--skip $(SKIP))

# The documentation site (docs/README.md): every page's code cells and every example notebook
# execute; warnings (a failing example, a broken link, an unresolved reference) are errors.
# FGOPT_EXECUTED_NOTEBOOKS=<dir of executed notebooks> reuses the test suite's runs (.ci/run).
# The pages' kernels use the test suite's kernel cache (tests/conftest.py: .pytest_cache/d/
# fgopt-kernels), as the doctests do, so after `make test` they load compiled kernels (~2 min
# on 2 cores) instead of compiling them again (~12 min); FGOPT_CACHE_DIR overrides it.
DOCS_CACHE := $(CURDIR)/.pytest_cache/d/fgopt-kernels
$(DOCS_STAMP): $(STAMP) pyproject.toml
	@$(PY) -c 'import sphinx, myst_nb, furo, sphinx_copybutton' 2>/dev/null || { \
	  echo "==> installing the docs extra into $(VENV)"; \
	  $(PY) -m pip install -q --disable-pip-version-check -e '.[docs]'; }
	@touch $(DOCS_STAMP)

docs: setup $(DOCS_STAMP)
	@FGOPT_DOCTESTS=1 $(PY) -m pytest -q -p no:xdist tests/test_docs_reference.py
	@FGOPT_CACHE_DIR="$${FGOPT_CACHE_DIR:-$(DOCS_CACHE)}" \
	  $(PY) -m sphinx -j auto -W --keep-going -b html docs docs/_build/html
	@echo "==> docs/_build/html/index.html"

clean:
	rm -rf $(VENV) build *.egg-info docs/_build docs/api/generated docs/gallery/notebooks docs/jupyter_execute
