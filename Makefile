# Two commands: `make demo` and `make test`. Each sets everything up first (idempotent):
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

.PHONY: setup demo test bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	@if ! dpkg -s $(APT_PACKAGES) >/dev/null 2>&1; then \
	  echo "==> installing $(APT_PACKAGES) (CHOLMOD for scikit-sparse, OpenBLAS for CHOLMOD)"; \
	  $(SUDO) apt-get install -y -q $(APT_PACKAGES) >/dev/null 2>&1 || \
	  { $(SUDO) apt-get update -q >/dev/null && $(SUDO) apt-get install -y -q $(APT_PACKAGES) >/dev/null; }; \
	fi
	@test -x $(PY) || { echo "==> creating $(VENV)"; python3 -m venv $(VENV); }
	@echo "==> installing fgopt and its dependencies into $(VENV)"
	@$(PY) -m pip install -q --disable-pip-version-check --upgrade pip wheel setuptools
	@$(PY) -m pip install -q --disable-pip-version-check -e '.[test,notebook,distributed,cholmod]'
	@touch $(STAMP)

demo: setup
	@$(PY) -m fgopt.demo

# One worker per core (at most 4), a test file per worker: 10.5 min instead of 17.7 on 2 cores
# with empty caches (numba compiles dominate and run single-threaded).
test: setup
	@$(PY) -m pytest -q -n auto --maxprocesses 4 --dist loadfile

# Regenerates every README table at HEAD (~75 min on 2 cores); `make bench SKIP=scale,gnc`
# for a shorter run (skipped tables keep their saved results and say so).
bench: setup
	@$(PY) -m pip install -q --disable-pip-version-check -e '.[bench]'
	@$(PY) -m benchmarks.run --all $(if $(SKIP),--skip $(SKIP))

clean:
	rm -rf $(VENV) build *.egg-info
