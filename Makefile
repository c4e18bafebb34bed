# Two entry points for a fresh machine (Python 3.11, git, make):
#   make study   set up .venv and run the full paper study (results/)
#   make test    set up .venv and run the tests, including the Snakemake smoke run
#   make report  (after make study) results/report.html: every figure captioned, run time per rule
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
CORES ?= 2
# an interrupted run (Ctrl-C, a killed job) resumes: outputs left incomplete are rebuilt
RESUME := --rerun-incomplete
# the rules call capsule-cli: the venv's bin comes first on PATH
export PATH := $(CURDIR)/$(BIN):$(PATH)

.PHONY: study test test-slow setup smoke report clean-results

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): $(BIN)/python pyproject.toml requirements.lock
	$(BIN)/python -m pip install --quiet -c requirements.lock -e '.[test]'
	touch $(STAMP)

setup: $(STAMP)

study: $(STAMP)
	$(BIN)/snakemake -s workflow/Snakefile --configfile configs/study.yaml --cores $(CORES) -p $(RESUME)

report: $(STAMP)
	$(BIN)/snakemake -s workflow/Snakefile --configfile configs/study.yaml --report results/report.html
	@echo "report: results/report.html"

smoke: $(STAMP)
	$(BIN)/snakemake -s workflow/Snakefile --configfile configs/smoke.yaml --cores $(CORES) -p $(RESUME)

# worksteal: a worker that runs out of tests takes some of the other's (the loop tests take 5-70 s each). Not
# loadgroup: with pytest 9.2 and pytest-xdist 3.8 it distributes as plain load (xdist renames item._nodeid, which
# pytest 9 no longer reads), so a test must not count on another one's run in the same process
test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(CORES) --dist worksteal -m "not slow"

# the dynamics-loop tests: minutes of engine time each, not part of CI's make test
test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -n $(CORES) --dist worksteal -m slow

clean-results:
	rm -rf results/*/ results/*.parquet
