# `make test` and `make run` each create .venv when missing and install the project into it.
# Afterwards: `. .venv/bin/activate`, or call `.venv/bin/routine-gym` and `.venv/bin/python`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# torch's CPU build comes first, from PyTorch's CPU wheel index beside the default index (the
# default index's Linux torch pulls CUDA, about 6 GB; the CPU build's version, 2.13.0+cpu, sorts
# above it, and torch's own dependencies come from the default index). Where the CPU index cannot
# be reached, torch comes from the default index; `make TORCH_INDEX=` skips the CPU index.
TORCH_VERSION := 2.13.0
TORCH_INDEX ?= https://download.pytorch.org/whl/cpu

.PHONY: test test-twins run lint bench clean

# The compiled cores are optional: without a C++17 compiler the install skips them (and says
# which); their Python twins run (docs/native.md).
$(STAMP): pyproject.toml setup.py $(wildcard routine_gym/_native/*.cpp routine_gym/_native/*.h)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	@if [ -n "$(TORCH_INDEX)" ]; then \
		echo "$(PY) -m pip install torch==$(TORCH_VERSION) --extra-index-url $(TORCH_INDEX)"; \
		$(PY) -m pip install --quiet --retries 1 --timeout 20 "torch==$(TORCH_VERSION)" \
			--extra-index-url "$(TORCH_INDEX)" \
		|| echo "make: $(TORCH_INDEX) could not be used; torch comes from the default index"; \
	fi
	$(PY) -m pip install --quiet -e ".[dev]"
	$(PY) -m routine_gym._native
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q -n 2 --durations=25 --doctest-modules routine_gym tests

# The Python twins are the product too: the tests of every script's smoke run, the wrapper,
# mining and MinAtar again with every compiled core turned off (docs/native.md), as .ci/run's
# second leg. About 2 minutes on 2 cores.
TWIN_TESTS := tests/test_native.py tests/test_wrapper.py tests/test_wrapper_step.py \
	tests/test_sequitur.py tests/test_mining.py tests/test_minatar.py \
	tests/test_minatar_vector.py tests/test_masked_gru.py tests/test_as_a_user.py
test-twins: $(STAMP)
	ROUTINE_GYM_NATIVE=0 $(PY) -m pytest -q -n 2 $(TWIN_TESTS) \
		-k "not test_as_a_user or each_script or mine_show"

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
