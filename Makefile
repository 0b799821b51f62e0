# Two entry points: `make run` (the main job, small default) and `make test`.
# Each creates .venv and installs the package on first use; later calls skip that.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test test-all docs bench reproduce compare clean mutate

BASE := $(VENV)/.installed-base

# make run needs the package alone; make test adds the test, Ray and docs tools (~240 MB more)
$(BASE): pyproject.toml setup.py
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e .
	touch $(BASE)

$(STAMP): $(BASE)
	$(BIN)/pip install -q -e ".[test,ray,docs]"
	touch $(STAMP)

run: $(BASE)
	$(BIN)/python scripts/train.py
	$(BIN)/python scripts/plot.py
	@echo "next: . $(VENV)/bin/activate (then python scripts/train.py --help, or trl-dgpq --help), or call $(BIN)/python directly"

# pytest-xdist: on this 2-core machine, quiet, 118 s against 188 s in one process (issue 30);
# worksteal: an idle worker takes tests queued on the other, so two long tests left at the end of
# one worker's share do not keep it running alone.
PYTEST := $(BIN)/python -m pytest -n auto --maxprocesses 4 --dist worksteal

test: $(STAMP)
	$(PYTEST)

# Everything, the slow checks too (real processes, Ray, long learning curves).
test-all: $(STAMP)
	@start=$$(date +%s); $(PYTEST) -m "" && echo "make test-all: $$(( $$(date +%s) - start )) s"

# The docs site (docs/, mkdocs.yml) into site/; `make test` builds it too, with --strict (tests/test_docs.py).
docs: $(STAMP)
	$(BIN)/mkdocs build --strict

# Mutation testing (mutmut; slow, so never in `make test` or CI), niced, with the tests that name
# the modules unless TESTS is given; K is a pytest -k expression, AGAIN=1 retests the last survivors:
#   make mutate MODULES="envs/f16 collectors/evaluate.py" [TESTS="tests/test_f16.py"] [K="not slow"]
# Per-module score (killed / total) and the survivors; see docs/testing.md and scripts/mutate.py.
mutate: $(STAMP)
	@test -n "$(MODULES)" || { echo 'make mutate MODULES="envs/f16 collectors/evaluate.py" [TESTS=...] [K=...]'; exit 2; }
	@$(BIN)/python -c "import mutmut" 2>/dev/null || $(BIN)/pip install -q -e ".[mutate]"
	nice -n 15 $(BIN)/python scripts/mutate.py $(MODULES) $(if $(TESTS),--tests $(TESTS)) $(if $(K),-k "$(K)") $(if $(AGAIN),--again)

reproduce: $(STAMP)
	$(BIN)/python scripts/reproduce.py

compare: $(STAMP)
	$(BIN)/python scripts/sweep.py configs/compare.toml --out runs/compare --seeds-per-job 5 --grow
	$(BIN)/python scripts/report.py runs/compare/*/ --out runs/compare

bench: $(STAMP)
	$(BIN)/python scripts/bench.py gp
	$(BIN)/python scripts/bench.py dgpq

# The venv and build output; never runs/ (hours of experiments): remove it yourself.
clean:
	rm -rf $(VENV) bench-*.json crash-check.json site mutants
