# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

SYSTEM := $(VENV)/.system

.PHONY: demo test bench firmware clean

# Debian packages (AVR toolchain, simavr, socat, openssl): installed when missing (root).
$(SYSTEM): .ci/system
	./.ci/system
	mkdir -p $(VENV) && touch $(SYSTEM)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/hexbench demo

firmware: $(SYSTEM) $(STAMP)
	$(MAKE) -C firmware PYTHON=$(abspath $(PY))

# Many tests wait on the wall clock (real-time fleets, simavr boots): xdist runs them side by side.
# .ci/system has installed every tool by now, so a test that finds one missing fails rather
# than skips (tests/support/toolchain.py); pyproject's -rs lists the skips that remain.
TEST := HEXBENCH_REQUIRE_TOOLS=1 $(PY) -m pytest
test: $(SYSTEM) $(STAMP) firmware
	$(VENV)/bin/lint-imports --no-logo
	$(TEST) -q -n 2 tests hexbench/conformance --ignore=tests/benchmarks
	$(TEST) -q --pyargs hexbench.conformance --hexbench-target firmware
	$(TEST) -q -n 8 --pyargs hexbench.conformance --hexbench-target simavr

bench: $(STAMP)
	$(PY) -m pytest -q -s tests/benchmarks

clean:
	rm -rf $(VENV) build *.egg-info
	$(MAKE) -C firmware clean
