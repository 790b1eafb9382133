# jaxcal: two commands after cloning: `make run` and `make test`.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
# JAX persistent compilation cache: compile time dominates on CPU.
export JAX_COMPILATION_CACHE_DIR := $(CURDIR)/.jax_cache
export JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS := 0.5
export JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES := 0
export MPLBACKEND := Agg
# numpy's BLAS threads only contend with XLA's on 2 cores (small products slow down 1000x under load).
export OPENBLAS_NUM_THREADS := 1

.PHONY: install run run-full test test-all clean

install: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

## The main job on built-in defaults: thesis reproduction, quick form -> results/
run: $(STAMP)
	$(BIN)/python -m experiments.run_all --quick

## The full-size reproduction (all seeds, full sweeps); takes much longer.
run-full: $(STAMP)
	$(BIN)/python -m experiments.run_all

test: $(STAMP)
	$(BIN)/python -m pytest -q -ra

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -ra -m ""

clean:
	rm -rf $(VENV) .jax_cache .pytest_cache
