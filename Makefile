# Every target that runs code depends on .venv, which is built from pyproject.toml
# alone: nothing relies on what happens to be installed on the machine.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
export MOTIONPHYSICS_CACHE ?= $(CURDIR)/.cache
OUT ?= runs/demo

.PHONY: demo test test-slow test-all lint bench gpu-check peers clean prior

$(BIN)/motionphysics: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	# torch first and alone: the pinned CPU build, so no dependency can pull a CUDA one.
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e '.[dev,all]'
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

# Speed and quality benchmarks (minutes; not part of the tests). The MPM comparison
# needs the peers' separate environment: `bash benchmarks/setup_peers.sh` once.
bench: $(BIN)/motionphysics
	$(BIN)/python benchmarks/bench_render.py --repeats 5
	$(BIN)/python benchmarks/bench_mpm.py --particles 20000 --substeps 100 --repeats 5
	$(BIN)/python benchmarks/bench_sysid.py --size fast

# One prepared GPU check (BENCHMARKS.md, "GPU check"): at most 9 minutes on one GPU, a JSON
# report and a markdown table; one line and exit 0 on a machine without CUDA. No .venv
# dependency: a GPU machine without internet cannot build it, so the script picks a Python
# whose torch sees the GPU. Arguments: make gpu-check GPU_CHECK_ARGS="--out FILE --parts ...".
gpu-check:
	bash benchmarks/gpu_check.sh $(GPU_CHECK_ARGS)

peers:
	bash benchmarks/setup_peers.sh

# The embedded motion prior from nothing (priors/MODEL_CARD_motion.md): simulated training and
# held-out clips, training, the held-out measures, the shippable weights. Resumable: rerun
# after an interruption. PRIOR_DATA holds the clips and the training checkpoint.
PRIOR_DATA ?= $(MOTIONPHYSICS_CACHE)/motion-prior
PRIOR_CLIPS ?= 1210
PRIOR_MIN ?= 13
prior: $(BIN)/motionphysics
	$(BIN)/motionphysics prior data $(PRIOR_DATA)/train --clips $(PRIOR_CLIPS) --workers 2 --seed 0
	$(BIN)/motionphysics prior data $(PRIOR_DATA)/held-out --clips 270 --workers 2 --seed 1 --held-out-shapes
	$(BIN)/motionphysics prior train $(PRIOR_DATA)/train --out $(PRIOR_DATA)/motion_prior.pt \
		--budget-min $(PRIOR_MIN) --threads 1 --resume
	$(BIN)/motionphysics prior eval $(PRIOR_DATA)/motion_prior.pt $(PRIOR_DATA)/held-out \
		--train-data $(PRIOR_DATA)/train \
		--snapshot tests/priors/data/motion_heldout_snapshot.npz > $(PRIOR_DATA)/eval.json
	$(BIN)/motionphysics prior export $(PRIOR_DATA)/motion_prior.pt \
		src/motionphysics/priors/motion_prior.pt --eval $(PRIOR_DATA)/eval.json

clean:
	rm -rf $(VENV) .cache runs
