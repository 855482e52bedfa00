# Two commands do all the set-up on a fresh Debian 12 machine:
#   make demo   solves the phantom pressed by four rigid tips, verifies the fast solvers, writes
#               a report under out/ (about 10 minutes on 2 cores)
#   make test   runs the test suite
# Each installs what is missing (apt-get as root, the venv, pip with constraints.txt), quickly when not.
# libopenblas0-pthread replaces Debian's reference BLAS (the default libblas3), which made every
# MUMPS factorization about 5x slower. gcc + python3-dev compile dolfinx's forms and the ADMM
# kernel (solvers/admm_kernel.c, built on first use). chromium (headless) draws every report
# page in the tests (TISSUE_NO_BROWSER=1 skips that check).
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
APT_PKGS := python3-dolfinx python3-gmsh python3-scipy python3-matplotlib python3-mpi4py \
            python3-meshio python3-h5py python3-venv python3-dev gcc make openmpi-bin \
            libopenblas0-pthread chromium
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: demo test system-deps venv bench lint clean

venv: $(STAMP)

system-deps:
	@if ! /usr/bin/python3 -c "import dolfinx, gmsh, scipy, matplotlib, meshio, h5py, ensurepip" >/dev/null 2>&1 \
	   || ! command -v mpirun >/dev/null || ! command -v gcc >/dev/null \
	   || ! command -v chromium >/dev/null \
	   || ! dpkg -s libopenblas0-pthread >/dev/null 2>&1; then \
	  echo "== installing Debian packages: $(APT_PKGS)"; \
	  $(SUDO) apt-get update -q && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -q --no-install-recommends $(APT_PKGS); \
	fi

$(STAMP): pyproject.toml constraints.txt
	@$(MAKE) --no-print-directory system-deps
	@[ -x $(PY) ] || /usr/bin/python3 -m venv --system-site-packages $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -c constraints.txt -e '.[dev]'
	@$(PY) -c "import numpy; assert numpy.__version__.startswith('1.24'), numpy.__version__"
	@touch $@

test: $(STAMP)
	@command -v chromium >/dev/null || [ "$${TISSUE_NO_BROWSER:-0}" != 0 ] \
	  || $(MAKE) --no-print-directory system-deps
	$(PY) -m pytest -q -ra --durations=15 tests

demo: $(STAMP)
	$(VENV)/bin/tissue demo --out out

bench: $(STAMP)
	for b in bench/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

lint: $(STAMP)
	$(VENV)/bin/ruff check .

clean:
	rm -rf out build *.egg-info
