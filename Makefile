# Two commands do everything on a fresh machine:
#   make demo   -> set up .venv with the base install (system libusb too, no torch), then run the demo
#   make test   -> add what the tests need (torch, torchvision, ray, pytest), then the whole test suite
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
BASE   := $(VENV)/.seedmap-base
TESTS  := $(VENV)/.seedmap-test
# --no-cache-dir: the CUDA build of torch is ~5.5 GB installed; caching its wheels too can fill a small disk.
PIP    := $(BIN)/python -m pip --no-cache-dir
# torch/torchvision for the learned detector's tests; pip finds these pinned wheels on this machine's disk.
TORCH_PINS ?= torch==2.14.1 torchvision==0.29.1

.PHONY: setup setup-test demo test test-fast bench docs clean

setup: $(BASE)

setup-test: $(TESTS)

$(BASE): pyproject.toml
	@bash scripts/install_system_deps.sh
	@avail=$$(df -Pk . | awk 'NR==2{print $$4}'); if [ "$$avail" -lt 4000000 ]; then echo "warning: $$((avail/1024)) MiB free here; the base environment (.venv) needs about 2.6 GB" >&2; fi
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q -e .
	@touch $@

$(TESTS): $(BASE)
	@avail=$$(df -Pk . | awk 'NR==2{print $$4}'); if [ "$$avail" -lt 7000000 ]; then echo "warning: $$((avail/1024)) MiB free here; the test extras (the CUDA build of torch) need about 6 GB more" >&2; fi
	$(PIP) install -q $(TORCH_PINS) || $(PIP) install -q "torch>=2.2,<3" "torchvision>=0.17,<1"
	$(PIP) install -q -e '.[learned,cluster,dev]'
	@touch $@

demo: $(BASE)
	$(BIN)/seedmap demo

test: $(TESTS)
	$(BIN)/python -m pytest -q -m "slow or not slow"

test-fast: $(TESTS)
	$(BIN)/python -m pytest -q

# the speed benchmarks that make their own data (the accuracy ones take datasets: benchmarks/README.md)
BENCH_SELF := bench_sim bench_slam bench_detect bench_recon bench_io bench_batch
bench: $(TESTS)
	@for b in $(BENCH_SELF); do echo "== $$b"; $(BIN)/python benchmarks/$$b.py || exit 1; done

# the results pages from benchmarks/results/*.json (standard library only)
docs:
	$(PYTHON) scripts/make_docs.py

clean:
	rm -rf $(VENV) build *.egg-info
