# Two commands for a user: `make run` (the paper's scenario) and `make test`. Both set up .venv.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run test setup build generate check-generated bench study sweep clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

setup: $(STAMP)

# Compile every generated/<spec>/ into build/<spec>/lib<spec>-<sources hash>.so (-O2 -fPIC, no fast-math).
build: $(STAMP)
	$(PY) -m acroboter.build

# Regenerate the C for every spec in model_spec/.
generate: $(STAMP)
	$(PY) -m codegen generate

# Regenerate into a temporary folder and compare file set and bytes with generated/.
check-generated: $(STAMP)
	$(PY) -m codegen check

run: build
	$(PY) -m acroboter.run

test: build
	$(PY) -m ruff check acroboter codegen tests
	$(PY) -m pytest -q

bench: build
	$(PY) -m acroboter.bench

# The redundancy / non-collocation study and the penalty-number sweep (Dask, local cluster).
study: build
	$(PY) -m acroboter.study

sweep: build
	$(PY) -m acroboter.sweep

clean:
	rm -rf build results
