# Two commands do everything on a fresh machine:
#   make demo   -> set up .venv (system libusb too), then run the main job on a built-in default
#   make test   -> same set-up, then the whole test suite (slow end-to-end tests included)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.seedmap-installed
# --no-cache-dir: the CUDA build of torch is ~5.5 GB installed; caching its wheels too can fill a small disk.
PIP    := $(BIN)/python -m pip --no-cache-dir
# torch/torchvision for the learned detector; pip finds these pinned wheels on this machine's disk.
TORCH_PINS ?= torch==2.14.1 torchvision==0.29.1

.PHONY: setup demo test test-fast bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	@bash scripts/install_system_deps.sh
	@avail=$$(df -Pk . | awk 'NR==2{print $$4}'); if [ "$$avail" -lt 10000000 ]; then echo "warning: $$((avail/1024)) MiB free here; the environment (.venv, with the CUDA build of torch) needs about 9 GB" >&2; fi
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q $(TORCH_PINS) || $(PIP) install -q "torch>=2.2,<3" "torchvision>=0.17,<1"
	$(PIP) install -q -e '.[learned,cluster,dev]'
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
