# Two commands do all set-up:  `make demo`  and  `make test`.
# torch is installed first, pinned to the CPU wheel (2.13.0): installing the project
# into an env without torch would let pip pull a CUDA build of several GB.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.multigrasp-installed
TORCH  := torch==2.13.0
WORKDIR ?= runs
# pip flags of the install steps (`make install PIP_OPTS=` shows pip's output).  Not PIP_QUIET: pip reads every
# PIP_<OPTION> variable of its environment, and make exports a variable set on its command line, so
# `make install PIP_QUIET=-q` made pip fail ("-q is not a valid value for quiet option").
PIP_OPTS ?= -q
# `make test` runs the suite in this many pytest-xdist worker processes, a test file per worker at a time
# (--dist loadfile: a module's shared fixtures, such as test_flows.py's smoke run, are built once). 2 suits
# 2 cores (fifty-fifth session, fresh clone: 10 min 16 s against 15 min 58 s in one process); TEST_WORKERS=0 runs in one.
TEST_WORKERS ?= 2
PYTEST_WORKERS := $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile)

.PHONY: install demo test test-fast bench clean-runs help

help:
	@echo "make demo   create .venv, install, run the smoke pipeline end to end"
	@echo "make test   install if needed, run the whole test suite"
	@echo "make bench  run the speed benchmarks (JSON in benchmarks/results/)"

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install $(PIP_OPTS) --upgrade pip
	$(BIN)/python -m pip install $(PIP_OPTS) $(TORCH)
	$(BIN)/python -m pip install $(PIP_OPTS) -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

# the smoke pipeline, then every evaluation of Table I and the report (the tables beside the paper's, in
# $(WORKDIR)/results/); a second `make demo` computes nothing
demo: install
	$(BIN)/multigrasp run --profile smoke --workdir $(WORKDIR) --evaluate
	@echo ""
	@echo "Stage outputs: $(WORKDIR)/stages/; tables: $(WORKDIR)/results/*.md (JSON beside them);"
	@echo "all of them beside the paper's: $(WORKDIR)/results/report.md"
	@echo "Status: $(BIN)/multigrasp status --workdir $(WORKDIR)"
	@echo "Open the MLflow UI:  $(BIN)/multigrasp ui --workdir $(WORKDIR)   then browse http://127.0.0.1:5000"

test: install
	$(BIN)/python -m pytest -q $(PYTEST_WORKERS)

test-fast: install
	$(BIN)/python -m pytest -q $(PYTEST_WORKERS) -m "not slow"

bench: install
	mkdir -p benchmarks/results
	$(BIN)/multigrasp bench kinematics --json benchmarks/results/kinematics.json

clean-runs:
	rm -rf $(WORKDIR)
