# hapid: one entry point. `make paper` and `make test` work on a machine with only Python.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
OUT    ?= out/paper
JOBS   ?= 2

.PHONY: setup paper test test-all lint bench clean

$(BIN)/hapid: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,hdf5]'
	touch $(BIN)/hapid

setup: $(BIN)/hapid

## main job: reproduce the paper's figures on the default simulated device
paper: setup
	$(BIN)/hapid paper --out $(OUT)

## the test suite (what CI runs)
test: setup
	$(BIN)/python -m pytest -q -m "not slow" -n $(JOBS) --dist loadfile

test-all: setup
	$(BIN)/python -m pytest -q -n $(JOBS) --dist loadfile

lint: setup
	$(BIN)/ruff check hapid tests benchmarks paper_figures
	$(BIN)/ruff format --check hapid tests benchmarks paper_figures

## benchmark suite → out/bench/report.md (`make bench BENCH=--quick` for the reduced run)
bench: setup
	$(BIN)/python -c "import skrf" 2>/dev/null || $(BIN)/pip install --quiet -e '.[bench]'
	$(BIN)/python benchmarks/run_all.py $(BENCH)

clean:
	rm -rf $(VENV) out .pytest_cache
