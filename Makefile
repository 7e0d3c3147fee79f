# wdss: run `make help` for the targets. Every target installs what it needs first.
.DEFAULT_GOAL := help
SHELL := /bin/bash

PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
# torch is pinned in constraints.txt so that no requirement can pull a CUDA build on a CPU machine.
PIP_INSTALL := $(PY) -m pip install --disable-pip-version-check -q -c constraints.txt
export MLFLOW_DISABLE_TELEMETRY ?= true

.PHONY: help setup setup-render setup-cluster test test-fast lint format train ui server bench data data-bench pack clean

help: ## list the targets
	@grep -E '^[a-zA-Z_-]+:.*## ' $(MAKEFILE_LIST) | sort | \
		awk 'BEGIN {FS = ":.*## "}; {printf "  \033[36m%-14s\033[0m %s\n", $$1, $$2}'

setup: $(VENV)/.installed ## create .venv and install wdss with its dev tools (pytest, ruff) and ONNX export

$(VENV)/.installed: pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP_INSTALL) -e '.[dev,export]'
	touch $@

setup-render: $(VENV)/.installed-render ## also install Blender's bpy (the `render` extra, ~400 MB)

$(VENV)/.installed-render: $(VENV)/.installed
	$(PIP_INSTALL) -e '.[dev,export,render]'
	touch $@

setup-cluster: $(VENV)/.installed-cluster ## also install the `cluster` extra (submitit launcher, PostgreSQL driver)

$(VENV)/.installed-cluster: $(VENV)/.installed
	$(PIP_INSTALL) -e '.[dev,export,cluster]'
	touch $@

data: setup-render ## render the default dataset (data/mini, a few minutes) ahead of training
	$(PY) -m wdss.render -cn mini

data-bench: setup-render ## render the benchmark dataset (data/bench: 54 scenes, noise ceilings; ~20 minutes on 2 cores, resumable)
	$(PY) -m wdss.render -cn bench

pack: setup-render ## pack data/mini into data/mini.packed (read patch by patch; training uses it when present)
	test -d data/mini || $(PY) -m wdss.render -cn mini
	$(PY) -m wdss.data.pack root=data/mini $(ARGS)

test: setup-render setup-cluster ## run the whole test suite, slow (rendering, DDP, server, launcher) tests included
	$(PY) -m pytest -n auto

test-fast: setup ## run the tests not marked slow
	$(PY) -m pytest -m "not slow"

lint: setup ## ruff: lint and format check
	$(PY) -m ruff check src tests
	$(PY) -m ruff format --check src tests

format: setup ## ruff: fix what can be fixed and format
	$(PY) -m ruff check --fix src tests
	$(PY) -m ruff format src tests

train: setup-render ## a short default training (renders data/mini on first use), tracked in MLflow; ARGS: overrides
	$(PY) -m wdss.train experiment=cpu $(ARGS)

# The store training logs to (conf/logger/mlflow.yaml): $MLFLOW_TRACKING_URI when set, else mlflow.db here.
TRACKING_URI := $(or $(MLFLOW_TRACKING_URI),sqlite:///mlflow.db)

ui: setup ## the MLflow UI on http://127.0.0.1:5000 (runs of $MLFLOW_TRACKING_URI, else mlflow.db)
ifneq ($(filter http://% https://%,$(TRACKING_URI)),)
	@echo "MLFLOW_TRACKING_URI is a tracking server, which serves its own UI: open $(TRACKING_URI)"
else
	@$(PY) -c "from wdss.tracking import runs_view_url; print('wdss: the training runs:', runs_view_url('$(TRACKING_URI)'))"
	$(VENV)/bin/mlflow ui --backend-store-uri '$(TRACKING_URI)' --host 127.0.0.1 --port 5000
endif

# A tracking server for several people or machines (README: "A team tracking server"): runs log to it over HTTP
# (MLFLOW_TRACKING_URI=http://127.0.0.1:$(SERVER_PORT)) and upload their artifacts through it (proxied) into
# SERVER_ARTIFACTS. Its own SQLite file: runs of mlflow.db keep their local artifact paths. PostgreSQL: README.
SERVER_STORE ?= sqlite:///$(CURDIR)/mlflow-server.db
SERVER_ARTIFACTS ?= $(CURDIR)/mlartifacts
SERVER_PORT ?= 5000
SERVER_WORKERS ?= 2

server: setup ## an MLflow tracking server on http://127.0.0.1:5000 (SQLite store, artifacts proxied to mlartifacts/)
	$(VENV)/bin/mlflow server --backend-store-uri '$(SERVER_STORE)' --artifacts-destination '$(SERVER_ARTIFACTS)' --host 127.0.0.1 --port $(SERVER_PORT) --workers $(SERVER_WORKERS)

bench: setup ## benchmarks: wavelet transforms against ptwt, data loading, model inference
	$(PY) -m wdss.bench wavelets
	$(PY) -m wdss.bench data
	$(PY) -m wdss.bench model

clean: ## remove caches (keeps .venv, data and mlflow.db)
	rm -rf .pytest_cache .ruff_cache src/*.egg-info
	find . -name __pycache__ -type d -not -path './.venv/*' -exec rm -rf {} +
