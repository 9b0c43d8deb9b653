# Quick start: `make run` (the whole pipeline) and `make test` (the test suite).
# Each creates .venv when it is missing and installs the project into it first.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test test-e2e lint typecheck bench docs setup clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet -e ".[test]"
	touch $(STAMP)

setup: $(STAMP)

run: $(STAMP)
	$(BIN)/stepzoo run --out results

# Lint and type-check first (they stop a broken tree before the long part), then the suite:
# one worker per core; a file's tests stay on one worker, so its module fixtures run once;
# files are handed out in the suite's order, the slow ones first (tests/conftest.py).
# The end-to-end group (pytest.mark.e2e: the tutorial's whole loop, a Dask cluster, a
# browser, `stepzoo run`'s whole pipeline, every built-in scenario planned, the stored
# plans compared) runs apart, in `make test-e2e`; CI (.ci/run) runs both.
# `make test` compiles with XLA's machine-code (LLVM) optimisation off: the same programs
# (XLA's own passes all run), about a fifth less compiling, which is most of the suite's
# time; results move by a rounding (no fused multiply-adds), which every test tolerates,
# as it must on another CPU. The end-to-end group compiles as users' runs do, with NumPy's
# AVX-512 kernels off (its sin, exp, arctan2... round otherwise there): the stored plans then
# reproduce on CPUs with and without AVX-512 (tests/test_plan_regression.py).
PYTEST := $(BIN)/python -m pytest -n auto --dist loadfile --no-loadscope-reorder
test: lint typecheck
	XLA_FLAGS="$$XLA_FLAGS --xla_backend_optimization_level=0" $(PYTEST) -m "not e2e"

NUMPY_WITHOUT_AVX512 := NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512F AVX512_SKX AVX512_ICL AVX512_SPR"
test-e2e: $(STAMP)
	$(NUMPY_WITHOUT_AVX512) $(PYTEST) -m e2e

lint: $(STAMP)
	$(BIN)/ruff check .

# mypy reads the library as the installed namespace stepzoo.* does: a tree of links laying the
# top-level folders out under stepzoo/ (mypy cannot see the editable install's import hook).
typecheck: $(STAMP)
	rm -rf .typecheck && mkdir -p .typecheck/stepzoo
	cp -rs $(CURDIR)/stepzoo/. .typecheck/stepzoo/
	for d in dynamics integrators bench search reports; do ln -s $(CURDIR)/$$d .typecheck/stepzoo/$$d; done
	cd .typecheck && $(CURDIR)/$(BIN)/mypy --config-file $(CURDIR)/pyproject.toml -p stepzoo

bench: $(STAMP)
	$(BIN)/pip install --quiet -e ".[bench]"
	$(BIN)/python -m bench.perf.run

# The docs site into site/, every warning an error; open site/index.html, no server needed.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

clean:
	rm -rf $(VENV) results site .typecheck
