# Every target that runs code depends on .venv, which is built from pyproject.toml
# alone: nothing relies on what happens to be installed on the machine.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
export MOTIONPHYSICS_CACHE ?= $(CURDIR)/.cache
OUT ?= runs/demo

.PHONY: demo test test-slow test-all lint bench clean

$(BIN)/motionphysics: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	# torch first and alone: the pinned CPU build, so no dependency can pull a CUDA one.
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e '.[dev]'
	touch $@

demo: $(BIN)/motionphysics
	$(BIN)/motionphysics demo --out $(OUT)

test: $(BIN)/motionphysics
	$(BIN)/python -m pytest -m "not slow and not cuda" -q

test-slow: $(BIN)/motionphysics
	$(BIN)/python -m pytest -m slow -q

test-all: $(BIN)/motionphysics
	$(BIN)/python -m pytest -q

lint: $(BIN)/motionphysics
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks

bench: $(BIN)/motionphysics
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf $(VENV) .cache runs
