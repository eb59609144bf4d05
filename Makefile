# The set-up contract: `make demo` and `make test` from a fresh clone.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
export MUJOCO_GL ?= egl

.PHONY: demo test lint bench clean

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	# viz: the demo writes a Rerun recording (demo.rrd) beside its pictures.
	$(PY) -m pip install --quiet -e ".[viz]"
	touch $@

$(VENV)/.installed-test: $(VENV)/.installed
	# Every extra the suite tests: recordings (viz), Minari datasets (record), Ray (ray).
	$(PY) -m pip install --quiet -e ".[test,viz,record,ray]"
	touch $@

demo: $(VENV)/.installed
	$(PY) -m mks_sim.kernels
	$(VENV)/bin/mks-sim demo

test: $(VENV)/.installed-test
	# worksteal: an idle worker takes queued tests from the busy one (the slow bin tests
	# bunched on one worker: 10.9 min with the default scheduling, 8.4 with worksteal)
	$(PY) -m ruff check mks_sim tests benchmarks
	$(PY) -m mypy
	# the numba kernels compiled once, shared out over both cores, before the test workers
	# (and the processes they start) would each compile them (mks_sim/kernels.py)
	$(PY) -m mks_sim.kernels --jobs 2
	$(PY) -m pytest -n 2 --dist worksteal -q --durations=15

bench: $(VENV)/.installed-test
	$(PY) -m pip install --quiet -e ".[bench]"
	# every benchmark alone, then RESULTS.md (BENCH_PROFILE=short: fewer seeds; see the script)
	PY=$(PY) benchmarks/run_all.sh

clean:
	rm -rf $(VENV) build dist *.egg-info .pytest_cache .mypy_cache .ruff_cache
