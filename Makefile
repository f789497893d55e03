# Two commands on a fresh clone: `make demo` and `make test`. Both bootstrap first
# (scripts/bootstrap.sh: .venv with ROS 2 wheels + colcon build; a warm run is instant).
PY := .venv/bin/python
SCENE ?= brittle_star
SECONDS ?= 10

.PHONY: bootstrap test demo bench mutation clean

bootstrap:
	@bash scripts/bootstrap.sh

test: bootstrap
	$(PY) -m pytest $(PYTEST_ARGS)

demo: bootstrap
	$(PY) -m softsnap_gaits.demo --scene $(SCENE) --seconds $(SECONDS) $(ARGS)

# Every benchmark script; each prints its own table (several minutes in all). The forward
# solver's accuracy regression check runs first and stops the run if accuracy was lost
# (it never fails on slowness).
bench: bootstrap
	@echo "== benchmarks/accuracy_check.py"; $(PY) benchmarks/accuracy_check.py || exit 1
	@for script in benchmarks/*_bench.py; do echo "== $$script"; $(PY) $$script || exit 1; done

# Seeded mutation testing of chosen files against chosen tests (not part of `make test`):
#   make mutation FILES=src/softsnap_driver/softsnap_driver/core.py TESTS=test/softsnap_driver/test_core.py
# Prints the score and every surviving mutant (file:line, the change); docs/testing.md.
MUTANTS ?= 120
SEED ?= 38
WORKERS ?= 1
mutation: bootstrap
	@test -n "$(FILES)" -a -n "$(TESTS)" || { echo 'usage: make mutation FILES="src/..." TESTS="test/..." [MUTANTS=120 SEED=38 WORKERS=1]'; exit 2; }
	nice -n 10 $(PY) scripts/mutation.py --files $(FILES) --tests $(TESTS) --mutants $(MUTANTS) --seed $(SEED) --workers $(WORKERS) $(ARGS)

clean:
	rm -rf .venv build runs
