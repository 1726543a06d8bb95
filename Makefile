# threedcal — `make all` runs the default study, `make test` the test suite, `make cluster-test` the study on Slurm.
# Both create .venv and install the pinned dependencies first (once; again when pyproject.toml changes).

SHELL  := /bin/bash
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
CORES  ?= 2
# The CPU torch wheel lives in /opt/wheels on our machines; pip looks there when it exists.
FIND_LINKS := $(if $(wildcard /opt/wheels),--find-links /opt/wheels,)

.PHONY: all smoke setup quick-study test lint bench report results-page clean cluster-test cluster-clean pretrained

all: $(STAMP)
	@start=$$(date +%s); \
	$(BIN)/snakemake --profile workflow/profiles/default --cores $(CORES) all; rc=$$?; \
	took=$$(( $$(date +%s) - start )); \
	echo "make all: the study took $$(( took / 60 )) min $$(( took % 60 )) s (exit $$rc); stage times in results/summary.md"; \
	exit $$rc

# A fast first run: the README's first scene (config/first_scene.yaml), results in results/my_digit/.
smoke: $(STAMP)
	$(BIN)/snakemake all --profile workflow/profiles/default --cores $(CORES) --configfile config/first_scene.yaml

setup: $(STAMP)

# The quick calibration against full calibrations over units (config/quick_study.yaml): every unit's
# dense collection, P = 80 models and quick run, then results/quick_study/. CPU heavy (hours on 2
# cores), not part of `all`; each simulated collection runs beside another.
quick-study: $(STAMP)
	@start=$$(date +%s); \
	nice -n 10 $(BIN)/snakemake quick_study --profile workflow/profiles/default --cores $(CORES) \
		--resources printer=$(CORES) --configfile config/quick_study.yaml; rc=$$?; \
	took=$$(( $$(date +%s) - start )); \
	echo "make quick-study took $$(( took / 60 )) min $$(( took % 60 )) s (exit $$rc) on $$(hostname): results/quick_study/"; \
	exit $$rc

# The weights shipped for `model.init: pretrained` (src/threedcal/pretrained/), rebuilt from simulated
# presses of many units and installed into the package: about an hour on 2 cores, not part of `all`.
pretrained: $(STAMP)
	$(BIN)/snakemake --profile workflow/profiles/default --cores $(CORES) pretrained
	$(BIN)/threedcal pretrained install results/pretrained

# The installer is uv (pinned, from the package registry): it installs the same versions as pip in
# less than half the time (a fresh clone's set-up 65 s -> 27 s here; uv's own step 20 s with its
# cache warm, 27 s with it empty). Where uv cannot be had or fails, pip installs instead and the
# set-up says so. Both byte-compile the dependencies, once: where PYTHONDONTWRITEBYTECODE is set
# (as on our development machines) Python would otherwise compile every import from source in every
# process, and the suite's Snakemake jobs took twice as long (the end-to-end test 228 s, not 113 s,
# with pip's --no-compile).
UV_VERSION := 0.13.9
install = $(BIN)/python -m pip install --quiet $(FIND_LINKS) uv==$(UV_VERSION) && \
	$(BIN)/python -m uv pip install --quiet --compile-bytecode --python $(BIN)/python $(FIND_LINKS) -e "$(1)" || \
	{ echo "set-up: uv could not install $(1); pip installs it instead"; \
	  $(BIN)/python -m pip install --quiet $(FIND_LINKS) -e "$(1)"; }

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(call install,.[dev])
	touch $(STAMP)

# The suite runs in TEST_WORKERS processes (pytest-xdist), handed out one test at a time in the order
# tests/conftest.py sets (the end-to-end run first, then the slow files); --durations lists where the time goes.
TEST_WORKERS ?= $(CORES)
test: $(STAMP)
	set -o pipefail; $(BIN)/python -m pytest -n $(TEST_WORKERS) --maxschedchunk 1 --durations=10 2>&1 | tee .pytest-last.log

# Every Python file of the repository (pyproject.toml's [tool.ruff]: *.py, less what git ignores),
# the workflow's rules and Snakemake's own lint.
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/snakefmt --check Snakefile rules
	$(BIN)/snakemake --lint --cores 1

# Benchmarks print figures and ratios against a baseline measured in the same run; they are not tests.
# bench_integrate times the authors' own fast_poisson: their wheel (py3DCal 1.1.0, from the package
# registry) is unpacked into .cache/ once; without it the bench says so and uses a re-expression.
PY3DCAL_DIR := .cache/py3dcal
export PY3DCAL_FAST_POISSON := $(CURDIR)/$(PY3DCAL_DIR)/py3DCal/model_training/lib/fast_poisson.py

$(PY3DCAL_FAST_POISSON): | $(STAMP)
	-$(BIN)/python -m pip download --quiet --no-deps py3dcal==1.1.0 -d $(PY3DCAL_DIR) && \
	  $(BIN)/python -m zipfile -e $(PY3DCAL_DIR)/py3dcal-1.1.0-py3-none-any.whl $(PY3DCAL_DIR)

bench: $(STAMP) $(PY3DCAL_FAST_POISSON)
	@set -e; for b in benchmarks/bench_*.py; do \
	  [ -e "$$b" ] || { echo "no benchmarks yet"; break; }; \
	  echo "== $$b"; $(BIN)/python "$$b"; \
	done

report: $(STAMP)
	$(BIN)/snakemake --profile workflow/profiles/default --cores $(CORES) all
	$(BIN)/snakemake --profile workflow/profiles/default --report report.html

# docs/results.md from a finished study's results folder (`make all` first; RESULTS=path for a
# study run elsewhere): every table with its protocol; the threedcal version, host and date.
RESULTS ?= results
results-page: $(STAMP)
	$(BIN)/threedcal report results-page $(RESULTS) --out docs/results.md

clean:
	rm -rf .snakemake results report.html

# The tiny study on a one-node Slurm started here, against a local run (docs/how-to/slurm.md). Needs root
# and apt-get: installs slurm-wlm, slurmdbd, munge and mariadb-server once (the names it added are
# kept in .cache/cluster/apt-installed.txt; `make cluster-clean` purges them) and the pip extra
# [cluster]; starts every daemon under a temporary directory and stops each by PID at the end.
CLUSTER_STAMP := $(VENV)/.cluster-installed

$(CLUSTER_STAMP): pyproject.toml | $(STAMP)
	$(call install,.[cluster])
	touch $(CLUSTER_STAMP)

cluster-test: $(STAMP) $(CLUSTER_STAMP)
	PYTHON=$(BIN)/python workflow/cluster/test.sh

cluster-clean:
	workflow/cluster/slurm.sh purge .cache/cluster/apt-installed.txt
