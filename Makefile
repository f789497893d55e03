# Two commands on a fresh clone: `make demo` and `make test`. Both bootstrap first
# (scripts/bootstrap.sh: .venv with ROS 2 wheels + colcon build; a warm run is instant).
PY := .venv/bin/python
SCENE ?= brittle_star
SECONDS ?= 10

.PHONY: bootstrap test demo bench clean

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

clean:
	rm -rf .venv build runs
