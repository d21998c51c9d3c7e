# Two commands for a user: `make run` (the paper's scenario) and `make test`. Both set up .venv.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
# Two stages: what a run needs (the package with every runtime extra), then what the tests and the docs need.
RUN_STAMP := $(VENV)/.installed-run
STAMP := $(VENV)/.installed
# Inside the checkout the cache of compiled libraries is build/cache/ (installed: the per-user cache);
# .venv/bin/acroboter finds it by itself, the export only makes it explicit for the tools run here.
export ACROBOTER_CACHE_DIR := $(CURDIR)/build/cache

.PHONY: run test test-long setup build generate check-generated mutation bench retiming-study shaping-study plan-fuzz study sweep robustness plant-fuzz plant-fuzz-cranes docs clean

$(RUN_STAMP): pyproject.toml setup.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[all]'
	touch $(RUN_STAMP)

# The test tools (pytest, hypothesis, sympy, mutmut, ...) and the docs site's: a first `make run` waits for
# none of them (measured 2026-12-02 without a pip cache, loaded machine: [all] 62 s, [all,test,docs] 193 s).
$(STAMP): $(RUN_STAMP)
	$(PY) -m pip install --quiet -e '.[all,test,docs]'
	touch $(STAMP)

setup: $(STAMP)

# Compile every generated/<spec>/ into build/cache/lib/<spec>-<sources hash>/lib<spec>.so (-O2 -fPIC, no
# fast-math); a library whose sources and flags did not change is not recompiled.
build: $(RUN_STAMP)
	$(PY) -m acroboter build

# Regenerate the C for every spec in model_spec/.
generate: $(RUN_STAMP)
	$(PY) -m acroboter generate

# Regenerate into a temporary folder and compare file set and bytes with generated/.
check-generated: $(RUN_STAMP)
	$(PY) -m acroboter check

# Mutation testing (mutmut, docs/mutation.md) of the runtime core modules, then the generator, in build/mutation/,
# two workers; MODULES="control/recovery.py sim/sensing.py" restricts it (CPU-heavy: one module takes minutes to
# an hour), SAMPLE=100 judges that many mutants drawn at random per selection (the report gives the interval).
MODULES ?=
SAMPLE ?=
mutation: $(STAMP) build
	$(PY) tools/mutation.py $(MODULES) $(if $(SAMPLE),--sample $(SAMPLE))

# The paper's scenario: compiles only the default crane's library (in parallel, a bar per file), on first use.
run: $(RUN_STAMP)
	$(PY) -m acroboter run
	@echo "the command line: $(CURDIR)/$(VENV)/bin/acroboter (or: source $(VENV)/bin/activate; acroboter --help)"

test: $(STAMP) build
	$(PY) -m ruff check acroboter tests tools setup.py
	$(PY) -m pytest -q -n auto --dist loadfile -m "not long" --durations=30

# The tests make test leaves out (tests/long_tests.txt: 10 s or more of a core each; make test keeps a sample of
# each kind).
test-long: $(STAMP) build
	$(PY) -m pytest -q -n auto --dist loadfile -m long --durations=30

bench: build
	$(PY) -m acroboter bench

# The redundancy / non-collocation study and the penalty-number sweep (Dask, local cluster).
# How fast the paper's path can be flown (docs/planning.md): both cranes, three winch limit sets, every method
# (two processes; about an hour on the shared 2-core VM).
retiming-study: build
	$(PY) tools/retiming_study.py --cases 0,1,2 & $(PY) tools/retiming_study.py --cases 3,4,5; wait
	$(PY) tools/retiming_study.py --assemble

# The paper's path input-shaped (ZV, ZVD, unshaped) on the same cases, every method (docs/planning.md, "Input
# shaping"; about 6 min on the shared 2-core VM).
shaping-study: build
	$(PY) tools/shaping_study.py --cases 0,1,2 & $(PY) tools/shaping_study.py --cases 3,4,5; wait
	$(PY) tools/shaping_study.py --assemble

# Paths nobody planned (docs/planning.md, "Paths nobody planned"): PATHS two- and three-edge paths drawn on both
# cranes, winch limits where the statics leave 5-20 % of the span, each planned to 0.1 mm and flown by every method
# with the limits applied (two processes; minutes per path): results/plan_fuzz/report.md.
PATHS ?= 20
plan-fuzz: build
	$(PY) tools/plan_fuzz.py --paths $(PATHS) --out results/plan_fuzz

study: build
	$(PY) -m acroboter study

sweep: build
	$(PY) -m acroboter sweep

# Monte Carlo over plants that differ from the model (Dask, local cluster): docs/robustness.md.
robustness: build
	$(PY) -m acroboter robustness

# Differential fuzzing of the plant against MuJoCo: 2,000 generated open-loop experiments over every example
# spec (Dask, two local workers; 53 min on the idle 2-core VM, 100 min under load): results/plant_fuzz/report.md,
# the last one in docs/plant-fuzz.md.
plant-fuzz: build
	$(PY) -m acroboter.plant_fuzz

# The same on 200 generated cranes (acroboter.model.crane_generator), each generated, compiled, checked for a pulling
# start, 10 open-loop experiments and every method closed loop on both plants: results/plant_fuzz_cranes/report.md,
# docs/plant-fuzz-cranes.md. Hours on the 2-core VM; CRANES=20 for a shorter one.
CRANES ?= 200
plant-fuzz-cranes: build
	$(PY) -m acroboter.plant_fuzz --cranes $(CRANES) --out results/plant_fuzz_cranes

# The documentation site (docs/, mkdocs.yml) into build/site/; --strict: a broken link, a missing API reference or a
# docstring the reference cannot read fails the build.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict

clean:
	rm -rf build results
