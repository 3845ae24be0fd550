# The two commands of the README's quick start, and a few more. Everything installs into .venv.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run test check bench screenshots clean-shm

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[test]'
	touch $(STAMP)

run: $(STAMP)            ## set up, then run the demo: PID joint control of a simulated PUMA 560
	$(BIN)/pbo run configs/pid_joint.yaml --duration 5

test: $(STAMP)           ## set up, then lint, type-check and run every test: those without processes first
	$(BIN)/ruff check --quiet pbo_runtime rtpu drivers modules bench tests tools
	$(BIN)/mypy
	$(BIN)/python -m pytest -q -m "not multiprocess"
	$(BIN)/python -m pytest -q -m multiprocess

check: $(STAMP)          ## check every shipped configuration
	@for f in configs/*.yaml; do $(BIN)/pbo check $$f || exit 1; done

bench: $(STAMP)          ## every benchmark against its baseline (about 25 minutes); rewrites docs/performance.md
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[bench]'
	$(BIN)/python -m bench

screenshots: $(STAMP)   ## the HMI's pictures in docs/, taken by its browser tests (needs chromium)
	PBO_SCREENSHOTS=docs $(BIN)/python -m pytest -q tests/test_hmi_engineer.py tests/test_hmi_user.py tests/test_hmi_monitor.py \
		tests/test_hmi_parallel.py

clean-shm: $(STAMP)      ## remove shared memory left by runs that crashed
	$(BIN)/pbo clean
