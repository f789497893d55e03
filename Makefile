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
	$(PY) scripts/demo.py --scene $(SCENE) --seconds $(SECONDS)

bench: bootstrap
	$(PY) benchmarks/run_all.py

clean:
	rm -rf .venv build runs
