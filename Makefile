# The set-up contract: `make demo` and `make test` from a fresh clone.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
export MUJOCO_GL ?= egl

.PHONY: demo test lint bench clean

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: $(VENV)/.installed
	$(PY) -m pip install --quiet -e ".[test]"
	touch $@

demo: $(VENV)/.installed
	$(VENV)/bin/mks-sim demo

test: $(VENV)/.installed-test
	$(PY) -m ruff check mks_sim tests benchmarks
	$(PY) -m mypy
	$(PY) -m pytest -n 2 -q

bench: $(VENV)/.installed-test
	$(PY) -m pip install --quiet -e ".[bench]"
	$(PY) benchmarks/spg.py

clean:
	rm -rf $(VENV) build dist *.egg-info .pytest_cache .mypy_cache .ruff_cache
