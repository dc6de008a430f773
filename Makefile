# Two entry points: `make train` (the main job) and `make test`.
# Both create .venv and install PyTorch first (TORCH, TORCH_FROM below), so that installing the
# package does not pull another build.
# `make install-ray` / `make test-ray`: a second venv, .venv-ray, with the `ray` optional group
# (RLlib pins gymnasium 1.2.2); README, "Scaling out".
PYTHON   ?= python3
VENV     ?= .venv
PY       := $(VENV)/bin/python
TORCH    ?= torch==2.13.0
# where pip finds it: this machine's wheel cache holds the CPU build; elsewhere give PyTorch's CPU
# index (make test TORCH_FROM="--index-url https://download.pytorch.org/whl/cpu"), or PyPI's
# default build of Linux, which is CUDA's, is installed
TORCH_FROM ?=
VENV_RAY ?= .venv-ray
PY_RAY   := $(VENV_RAY)/bin/python
# pytest worker processes (pytest-xdist; a worker takes the tests another has not started when it
# runs out): auto, one per core up to 8 (a worker took up to 1.6 GB here); 0 runs the suite in this
# process
WORKERS  ?= auto
XDIST    := -n $(WORKERS) --maxprocesses 8 --dist worksteal

.PHONY: install train test lint bench clean install-ray test-ray

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet "$(TORCH)" $(TORCH_FROM)
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $@

install: $(VENV)/.installed

train: install
	$(PY) train.py $(ARGS)

test: install
	$(PY) -m ruff check .
	$(VENV)/bin/lint-imports --no-cache --no-logo
	$(PY) -m imm_gym.precompile
	$(PY) -m pytest $(XDIST) $(ARGS)

$(VENV_RAY)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV_RAY)
	$(PY_RAY) -m pip install --quiet --upgrade pip
	$(PY_RAY) -m pip install --quiet "$(TORCH)" $(TORCH_FROM)
	$(PY_RAY) -m pip install --quiet -e ".[dev,ray]"
	touch $@

install-ray: $(VENV_RAY)/.installed

# The kernels compiled, the Ray tests (tests/ray: a two-node cluster on this machine), then the
# core suite under the gymnasium that RLlib pins.
test-ray: install-ray
	$(PY_RAY) -m imm_gym.precompile
	$(PY_RAY) -m pytest -m ray tests/ray $(ARGS)
	$(PY_RAY) -m pytest $(XDIST) -m "not slow and not ray" $(ARGS)

bench: install
	$(PY) benchmarks/bench_imm.py

clean:
	rm -rf $(VENV) $(VENV_RAY) build *.egg-info .pytest_cache .ruff_cache .hypothesis
