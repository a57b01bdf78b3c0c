# Two entry points that do all set-up on a fresh Linux machine with Python 3.10+:
#   make demo   - the whole pipeline on the built-in default (simulated camera, bundled model)
#   make test   - the test suite
VENV ?= .venv
PYTHON ?= python3
BIN := $(VENV)/bin
DEMO_SECONDS ?= 30
# setuptools reports every editable install of a package-dir layout like ours ("Editable installation...
# folders with the same name as your package"): information, not a problem; every other warning still shows.
PIP_INSTALL := PYTHONWARNINGS="ignore:Editable installation" $(BIN)/python -m pip install --quiet

.PHONY: demo test bench clean

# The C sources are prerequisites so an existing venv recompiles the kernels after an edit. The install
# is quiet; native_report says so when a kernel did not compile (the numpy twin runs then, slower).
$(BIN)/courtloc-runtime: pyproject.toml setup.py scan/scan_kernel.c localizer/fit_kernel.c localizer/search_kernel.c
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(PIP_INSTALL) -e .
	$(BIN)/python -m courtloc.native_report
	touch $@

# The test venv adds pytest only: no torch (its default wheel is the multi-GB CUDA build). The paper
# network's tests skip with the reason without it; .ci/run installs the CPU build and runs them.
$(BIN)/courtloc-test: $(BIN)/courtloc-runtime
	$(PIP_INSTALL) -e '.[test]'
	touch $@

# The demo keeps its model store in the checkout (git-ignored): a model pushed to another clone, or to
# this user's default store, is not what the demo serves.
DEMO_STORE ?= .demo-store
demo: $(BIN)/courtloc-runtime
	$(BIN)/courtloc up --duration $(DEMO_SECONDS) --summary-json demo-summary.json --model-store $(DEMO_STORE)

test: $(BIN)/courtloc-test
	$(BIN)/python -m pytest -q

bench: $(BIN)/courtloc-runtime
	$(BIN)/courtloc bench pipeline --json bench-pipeline.json

clean:
	rm -rf $(VENV) $(DEMO_STORE) demo-summary.json bench-*.json
