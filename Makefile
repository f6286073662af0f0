# `make test` and `make run` each create .venv when missing and install the project into it.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: test run lint bench clean

# The compiled cores are optional: without a C++17 compiler the install skips them (and says
# which); their Python twins run (docs/native.md).
$(STAMP): pyproject.toml setup.py $(wildcard routine_gym/_native/*.cpp routine_gym/_native/*.h)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q -n 2 --doctest-modules routine_gym tests

# RAPL-A2C on Qbert from the shipped demo, with a budget that ends in about 10 minutes on a
# 2-core CPU; the paper's budget is `python algos/rapl_a2c.py --env-id ALE/Qbert-v5` (10M steps).
run: $(STAMP)
	$(VENV)/bin/routine-gym mine demos/ALE-Qbert-v5.npz
	$(PY) algos/rapl_a2c.py --env-id ALE/Qbert-v5 --total-timesteps 200000 --eval-episodes 3 \
		--log-every 10000

lint: $(STAMP)
	$(VENV)/bin/ruff check routine_gym algos tests bench

bench: $(STAMP)
	$(PY) bench/bench_mining.py
	$(PY) bench/bench_wrapper.py

clean:
	rm -rf $(VENV) build *.egg-info
