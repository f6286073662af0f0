# `make test` and `make run` each create .venv when missing and install the project into it.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: test run lint bench clean

$(STAMP): pyproject.toml setup.py routine_gym/_sequitur.cpp
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q -n 2 tests

run: $(STAMP)
	$(VENV)/bin/routine-gym mine demos/MiniQbert-v0.npz

lint: $(STAMP)
	$(VENV)/bin/ruff check routine_gym algos tests bench

bench: $(STAMP)
	$(PY) bench/bench_mining.py
	$(PY) bench/bench_wrapper.py

clean:
	rm -rf $(VENV) build *.egg-info
