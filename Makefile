# jaxcal: two commands after cloning: `make run` and `make test`.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
# The exact versions the suite was last run with (`make lock` refreshes it; `make test-latest` tries newer).
LOCK    := constraints.txt
# One worker per core, one test file per worker (module fixtures are built once; `-n 0` runs serially);
# the 30 slowest steps are listed, since the suite is the loop every change goes through. The CPUs are the
# limit: 3 workers on 2 cores ran the suite in 756 s (196 % CPU), 2 in 705 s (threshold 0.5 below, both; one run each).
PYTEST_ARGS ?= -q -ra -n auto --dist loadfile --durations=30
# JAX persistent compilation cache: compile time dominates on CPU. Every compile is kept (threshold 0): the
# suite's modules and its two workers compile many of the same small programs (jax.clear_caches after each
# module, tests/conftest.py), and a load from disk is cheaper than compiling again. Fresh clones of one commit,
# one after the other on the 2-core machine: pytest 575 s at threshold 0 against 705 s at 0.5 (one run each; runs of one
# commit vary by up to 18 % on this machine, so this is not a measured ratio).
export JAX_COMPILATION_CACHE_DIR := $(CURDIR)/.jax_cache
export JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS := 0
export JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES := 0
export MPLBACKEND := Agg
# numpy's BLAS threads only contend with XLA's on 2 cores (small products slow down 1000x under load).
export OPENBLAS_NUM_THREADS := 1

.PHONY: install lock run run-full run-real bench lint test test-all test-latest margins dist clean

install: $(STAMP)

$(STAMP): pyproject.toml $(LOCK)
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c $(LOCK) -e ".[dev]"
	touch $(STAMP)

## Refresh $(LOCK): the newest versions pyproject allows, installed in a scratch venv and frozen.
lock:
	rm -rf .venv-lock && $(PY) -m venv .venv-lock
	.venv-lock/bin/python -m pip install --quiet --upgrade pip
	.venv-lock/bin/python -m pip install --quiet ".[dev]"
	{ echo "# Exact versions for 'make install' (pip -c): written by 'make lock' on Python $$(.venv-lock/bin/python -c 'import platform; print(platform.python_version())'), $$(date -u +%Y-%m-%d)."; \
	  .venv-lock/bin/python -m pip freeze --exclude jaxcal; } > $(LOCK).tmp && mv $(LOCK).tmp $(LOCK)
	rm -rf .venv-lock

## The main job on built-in defaults: thesis chapters 3-4 (and beyond), 2 seeds -> results/*_quick.* (git-ignored)
run: $(STAMP)
	$(BIN)/python -m experiments.run_all --quick

## The complete chapter 3-4 reproduction: Table 3.1 (8 sizes x 5 seeds), Tables 4.1-4.2 (5 seeds), all figures
run-full: $(STAMP)
	$(BIN)/python -m experiments.run_all

## Public recordings and `jaxcal diagnose` (quick forms; the full forms: each script without --quick)
run-real: $(STAMP)
	$(BIN)/python -m experiments.run_all --group real --quick

## The performance record (results/performance.{md,json}) with every key measured: installs the optional
## `bench` extra (PyTorch's CPU build, for `jax_vs_torch`), then `benchmarks/run.py --quick` (about 7 min on 2 quiet cores).
bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -c $(LOCK) -e ".[bench]"
	$(BIN)/python benchmarks/run.py --quick

## The sdist and wheel users install (`pip install dist/jaxcal-*.whl`); tests/test_packaging.py builds them too.
dist: $(STAMP)
	$(BIN)/python -m build --outdir dist .

## Lint (pyflakes, pycodestyle errors, import order; config in pyproject.toml): a second of work, run first by `make test`.
lint: $(STAMP)
	$(BIN)/ruff check jaxcal experiments tests benchmarks data/convert.py

# The suite compiles with XLA:CPU's classic fusion emitters, not the newer MLIR ones (jaxlib 0.10's default).
# Compiling is most of the suite's time, and the classic emitters compile faster. Fresh-clone `.ci/run` on the
# 2-core machine, all 905 tests passing in every run: two pairs, each run right after the other, gave pytest
# 657.6 s (default) against 542.0 s (flag), and 486.0 s (default) against 374.0 s (the flag's run before it);
# five runs of the flagged commit took 360-539 s, median 415.5 s (the machine's speed drifted that much). Programs run
# somewhat slower (tests/test_diagnose_noref.py alone, serially: compile 39.0 -> 25.8 s, the rest 24.5 -> 27.3 s).
# Only the tests' own processes get it: `make run`, `make bench` and users keep jax's default. Results do not hang
# on it: a verdict never hangs on code generation (tolerances carry measured deviations). An XLA without the flag
# refuses to start ("Unknown flags in XLA_FLAGS"): drop it here then.
test test-all: export XLA_FLAGS := --xla_cpu_use_fusion_emitters=false $(XLA_FLAGS)

test: $(STAMP) lint
	$(BIN)/python -m pytest $(PYTEST_ARGS)

test-all: $(STAMP)
	$(BIN)/python -m pytest $(PYTEST_ARGS) -m ""

## The suite on the newest versions pyproject allows, in a separate venv (.venv-latest).
test-latest:
	test -x .venv-latest/bin/python || $(PY) -m venv .venv-latest
	.venv-latest/bin/python -m pip install --quiet --upgrade pip
	.venv-latest/bin/python -m pip install --quiet --upgrade --upgrade-strategy eager -e ".[dev]"
	.venv-latest/bin/python -m pip freeze --exclude jaxcal | diff -I '^#' $(LOCK) - || true
	.venv-latest/bin/python -m pytest $(PYTEST_ARGS)

## Near-threshold scan: the suite five times (cold and warm compilation cache, other hash seeds,
## two host devices, serial with single-threaded Eigen), every numeric assertion's margin logged,
## then a sixth, informative run with XLA's fast math (reassociated sums: how far each value moves
## when reduction order changes; its failures do not stop the scan) -> results/margins.md
MARGINS := .margins
margins: $(STAMP)
	rm -rf $(MARGINS) && mkdir -p $(MARGINS)
	JAXCAL_MARGIN_LOG=$(MARGINS)/1_cold.jsonl JAX_COMPILATION_CACHE_DIR=$(CURDIR)/$(MARGINS)/cache $(BIN)/python -m pytest $(PYTEST_ARGS) -p no:cacheprovider
	JAXCAL_MARGIN_LOG=$(MARGINS)/2_warm.jsonl JAX_COMPILATION_CACHE_DIR=$(CURDIR)/$(MARGINS)/cache $(BIN)/python -m pytest $(PYTEST_ARGS) -p no:cacheprovider
	JAXCAL_MARGIN_LOG=$(MARGINS)/3_hashseed.jsonl PYTHONHASHSEED=12345 $(BIN)/python -m pytest $(PYTEST_ARGS) -p no:cacheprovider
	JAXCAL_MARGIN_LOG=$(MARGINS)/4_devices2.jsonl XLA_FLAGS=--xla_force_host_platform_device_count=2 PYTHONHASHSEED=7 $(BIN)/python -m pytest $(PYTEST_ARGS) -p no:cacheprovider
	JAXCAL_MARGIN_LOG=$(MARGINS)/5_serial.jsonl PYTHONHASHSEED=99 XLA_FLAGS=--xla_cpu_multi_thread_eigen=false $(BIN)/python -m pytest -q -ra -n 0 -p no:cacheprovider
	-JAXCAL_MARGIN_LOG=$(MARGINS)/6_fastmath.jsonl XLA_FLAGS=--xla_cpu_enable_fast_math=true JAX_COMPILATION_CACHE_DIR=$(CURDIR)/$(MARGINS)/cache_fm $(BIN)/python -m pytest $(PYTEST_ARGS) -p no:cacheprovider
	$(BIN)/python -m tests.margins $(MARGINS)/[1-5]_*.jsonl --perturbed $(MARGINS)/6_fastmath.jsonl > results/margins.md

clean:
	rm -rf $(VENV) .venv-latest .venv-lock $(MARGINS) .jax_cache .pytest_cache build dist
