# The two set-up commands of the README: `make demo` and `make test`.
# Both create .venv (idempotently: re-installs only when pyproject.toml or constraints.txt change);
# `make test` first installs what the tests need outside Python (chromium: scripts/system-deps.sh).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint install system-deps clean-venv gpu-carry gpu-check

$(STAMP): pyproject.toml constraints.txt
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[dev]"
	@touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/seeu demo --out out/demo

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

system-deps:
	@scripts/system-deps.sh

test: system-deps lint
	$(BIN)/python -m pytest -q --durations=15 tests

clean-venv:
	rm -rf $(VENV)

# The GPU check (benchmarks/gpu_check.py, at most 8 minutes on one H100). gpu-carry runs where a package
# index is and fills .gpu_carry/ (gsplat's sources, pure-Python packages a bare GPU machine may lack);
# gpu-check runs on the GPU machine with the working tree and .gpu_carry/, with its own python3.
gpu-carry: $(STAMP)
	$(BIN)/python benchmarks/gpu_carry.py

gpu-check:
	$(PYTHON) benchmarks/gpu_check.py --write --json out/gpu_check.json
