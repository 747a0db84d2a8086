# The two commands a new user needs: `make dataset` and `make test`. Each sets up .venv first when needed.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
CONFIG ?= configs/default.yaml
OUT    ?= out
JOBS   ?= 0
STAMP  := $(VENV)/.installed
# torch's CPU build, installed before the `learn` extra so that extra adds nothing heavy (a plain `torch` from the
# registry is a multi-GB CUDA build). With a GPU: install your torch first and run `make setup TORCH=` (skips it).
TORCH  ?= torch==2.13.0

.DEFAULT_GOAL := help
.PHONY: help setup dataset test bench repro lint clean

help: ## List the targets
	@grep -E '^[a-z]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-8s %s\n", $$1, $$2}'
	@echo "  variables: CONFIG=$(CONFIG) OUT=$(OUT) JOBS=$(JOBS) (0 = all cores)"

setup: $(STAMP) ## Create .venv and install the package with its test tools

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(if $(TORCH),$(BIN)/pip install --quiet $(TORCH))
	$(BIN)/pip install --quiet -e '.[dev,dask,learn]'
	@touch $(STAMP)

dataset: $(STAMP) ## Run every stage of CONFIG into OUT (finished work is skipped)
	$(BIN)/gen run --config $(CONFIG) --out $(OUT) --jobs $(JOBS)
	@echo "published: $(OUT)/dataset (card: $(OUT)/dataset/card.md, plots: $(OUT)/dataset/plots/)"

test: $(STAMP) ## Run the test suite
	$(BIN)/python -m pytest -q

bench: $(STAMP) ## Run the throughput benchmarks (writes bench/results*.json; experiments: studies/)
	@for b in bench/bench_*.py; do m=bench.$$(basename $$b .py); echo "== $$m"; $(BIN)/python -m $$m || exit 1; done

repro: $(STAMP) ## Check byte-reproducibility: jobs 1 vs 2, and kill -9 then resume
	$(BIN)/python -m pipeline.repro --config configs/smoke.yaml --workdir build/repro -- $(BIN)/gen

lint: $(STAMP) ## ruff, the layer contracts (import-linter) and the module/function sizes (see ARCHITECTURE.md)
	$(BIN)/ruff check pipeline graspgen stages graspgen_cli shared_utils tests bench studies assets tools
	$(BIN)/lint-imports --no-cache
	$(BIN)/python tools/check_sizes.py graspgen pipeline stages graspgen_cli shared_utils

clean: ## Remove OUT and build products (keeps .venv and the CoACD cache in .cache)
	rm -rf $(OUT) build
