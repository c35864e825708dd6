# Two commands do everything on a fresh machine:
#   make demo   -> set up .venv (system libusb too), then run the main job on a built-in default
#   make test   -> same set-up, then the whole test suite (slow end-to-end tests included)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.seedmap-installed
# torch/torchvision for the learned detector; pip finds these pinned wheels on this machine's disk.
TORCH_PINS ?= torch==2.14.1 torchvision==0.29.1

.PHONY: setup demo test test-fast bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	@bash scripts/install_system_deps.sh
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q $(TORCH_PINS) || $(BIN)/python -m pip install -q "torch>=2.2,<3" "torchvision>=0.17,<1"
	$(BIN)/python -m pip install -q -e '.[learned,cluster,dev]'
	@touch $(STAMP)

demo: setup
	$(BIN)/seedmap demo

test: setup
	$(BIN)/python -m pytest -q -m "slow or not slow"

test-fast: setup
	$(BIN)/python -m pytest -q

bench: setup
	@for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
