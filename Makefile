# borescan: the two commands a fresh machine needs are `make run` and `make test`.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
CORES  ?= 2
DEMO   := data/demo

.PHONY: run test bench demo lint clean-results help

help:
	@echo "make run    - install, generate the demo nights, run the pipeline (results/)"
	@echo "make test   - install, run the test suite"
	@echo "make bench  - run the benchmarks, a contract night first (ratios measured side by side)"

$(STAMP): requirements.lock pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) (Python 3.11) on PATH"; exit 1; }
	@date +%s > .install-started
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r requirements.lock
	$(BIN)/python -m pip install --quiet --no-deps -e .
	@echo "install: $$(( $$(date +%s) - $$(cat .install-started) )) s"; rm -f .install-started
	touch $(STAMP)

$(DEMO)/.complete: $(STAMP)
	$(BIN)/borescan simulate demo --out $(DEMO)

demo: $(DEMO)/.complete

run: $(STAMP) $(DEMO)/.complete
	@start=$$(date +%s); PATH=$(abspath $(BIN)):$$PATH $(BIN)/snakemake --cores $(CORES) && \
	  echo "pipeline: $$(( $$(date +%s) - start )) s on $(CORES) cores"
	@echo ""
	@echo "Results are in results/ : open results/report.html; history: $(BIN)/borescan sql \"SELECT * FROM scans\""

test: $(STAMP) lint
	PATH=$(abspath $(BIN)):$$PATH $(BIN)/python -m pytest -q

bench: $(STAMP)
	PATH=$(abspath $(BIN)):$$PATH $(BIN)/python -m bench

lint: $(STAMP)
	$(BIN)/ruff check
	tmp=$$(mktemp -d) && trap 'rm -rf "$$tmp"' EXIT && mkdir "$$tmp/raw" && \
	  PATH=$(abspath $(BIN)):$$PATH $(BIN)/snakemake --lint --config raw_root=$$tmp/raw results_root=$$tmp/results

clean-results:
	rm -rf results
