# The two commands a newcomer needs: `make demo` and `make test`.
# Each creates .venv when missing and (re)installs the project when pyproject.toml changed.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.goniobench-installed

.PHONY: demo test bench-perf clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test,scale,parquet,mitsuba,bluesky]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/bench demo --out demo-out

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench-perf: $(STAMP)
	$(BIN)/python -m benchmarks

clean:
	rm -rf $(VENV) demo-out .pytest_cache
