# The two commands a newcomer needs: `make demo` and `make test`.
# Each runs `make install`: creates .venv when missing and (re)installs the project when
# pyproject.toml changed. `make test` runs the suite less the tests marked `slow`, on
# $(WORKERS) pytest-xdist workers (numba's on-disk kernel cache is shared by them) that steal
# tests from each other's queue (`--dist worksteal`: no worker idles while a long file keeps
# the other busy; 236 s against 256 s for whole files per worker, same load, 2 cores);
# `make test-slow` runs only those, `make test-all` both (CI runs both).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.goniobench-installed
# The docs site's generator (the `docs` extra): installed by `make docs` and `make test-slow` (which
# builds the site), not by `make test`, whose fresh-clone time it would lengthen.
DOCS_STAMP := $(VENV)/.goniobench-docs-installed
WORKERS ?= 2
PYTEST := $(BIN)/python -m pytest -q -n $(WORKERS) --dist worksteal

.PHONY: install demo test test-slow test-all bench-perf soak llvm docs kernels clean

# Mitsuba's LLVM variants (the benchmark's anchor, vectorized Mitsuba specimens) need a libLLVM:
# Debian's libllvm19, installed here when missing and apt-get can (as root); never fatal --
# without it those rows say "not available" and the LLVM tests skip, saying why.
LIBLLVM ?= /usr/lib/x86_64-linux-gnu/libLLVM-19.so
llvm:
	@if [ ! -e "$(LIBLLVM)" ] && command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null) \
	    || echo "libllvm19 could not be installed: Mitsuba's LLVM rows and tests will say why"; \
	fi

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# pip byte-compiles all 12,000 installed files one by one (half of the install's time), though a
# command imports a fraction of them: it installs without, and each module is compiled the first time
# it is imported, once -- the recipes here write bytecode even where PYTHONDONTWRITEBYTECODE is set
# (unexported below), so the install's kernel warm-up, the demo and the tests leave every module
# they import compiled, and a user's commands read it.
unexport PYTHONDONTWRITEBYTECODE
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --no-compile -e ".[test,scale,parquet,mitsuba,bluesky,tiled]"
	touch $(STAMP)

# The project with every extra its tests use, the kernel code generated from the laws (make
# kernels), its bytecode (so commands do not recompile our sources each run), and every numba kernel
# compiled into the on-disk cache, two processes at a time (seconds when current), which also leaves
# the modules the commands import compiled.
install: $(STAMP)
	@$(BIN)/python -m virtual.kernels.generate >/dev/null
	@$(BIN)/python -m compileall -q bench virtual drivers compare >/dev/null
	$(BIN)/python -m bench.compilation

# The kernel code written from the scattering laws (virtual/kernels/laws/*.py): their float32 twins
# and every kernel path's dispatch -- build products, not checked in (git ignores them: a copy per
# precision is not a second source; importing virtual.kernels also writes them when missing or
# stale) -- and the checked-in numba-free law table. Writes only the files whose text differs. Run
# after adding or editing a law; tests/test_kernels_generated.py fails while the table is stale.
kernels: | $(STAMP)
	$(BIN)/python -m virtual.kernels.generate

demo: install
	$(BIN)/bench demo --out demo-out

test: install llvm
	$(PYTEST) -m "not slow"

$(DOCS_STAMP): pyproject.toml | $(STAMP)
	$(BIN)/python -m pip install --quiet --no-compile -e ".[docs]"
	touch $(DOCS_STAMP)

test-slow: install llvm $(DOCS_STAMP)
	$(PYTEST) -m slow

test-all: test test-slow

bench-perf: install llvm
	@if [ -e "$(LIBLLVM)" ]; then export DRJIT_LIBLLVM_PATH="$${DRJIT_LIBLLVM_PATH:-$(LIBLLVM)}"; fi; \
	$(BIN)/python -m benchmarks

# Fault-injection soak on the emulated bench (benchmarks/soak.py): SOAK_MINUTES=60 by default.
SOAK_MINUTES ?= 60
soak: install
	$(BIN)/python -m benchmarks soak --minutes $(SOAK_MINUTES) --json

# The generated blocks of the README and docs/ (the specimen-family table) rewritten from the
# declarations, then the docs site (mkdocs.yml) built into build/site with warnings as errors.
docs: $(DOCS_STAMP)
	$(BIN)/python -m bench.docs
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict --quiet

clean:
	rm -rf $(VENV) demo-out .pytest_cache build/site
