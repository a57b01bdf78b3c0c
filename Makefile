# Two entry points that do all set-up on a fresh Linux machine with Python 3.10+:
#   make demo   - the whole pipeline on the built-in default (simulated camera, bundled model)
#   make test   - the test suite
VENV ?= .venv
PYTHON ?= python3
BIN := $(VENV)/bin
DEMO_SECONDS ?= 30

.PHONY: demo test bench clean

# The C sources are prerequisites so an existing venv recompiles the kernels after an edit.
$(BIN)/courtloc-runtime: pyproject.toml scan/scan_kernel.c localizer/fit_kernel.c
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e .
	touch $@

# The test venv adds pytest and the training extra (torch pinned to the CPU build).
$(BIN)/courtloc-test: $(BIN)/courtloc-runtime
	$(BIN)/python -m pip install --quiet -e '.[test,train]' -c deploy/constraints-cpu.txt
	touch $@

demo: $(BIN)/courtloc-runtime
	$(BIN)/courtloc up --duration $(DEMO_SECONDS) --summary-json demo-summary.json

test: $(BIN)/courtloc-test
	$(BIN)/python -m pytest -q

bench: $(BIN)/courtloc-runtime
	$(BIN)/courtloc bench pipeline --json bench-pipeline.json

clean:
	rm -rf $(VENV) demo-summary.json bench-*.json
