# Entry points for a new user (see README): `make demo` (a two-minute train + the committed model's evaluation),
# `make test-fast` (all but the tests marked slow), `make test` (everything, as CI), `make lint` (ruff + mypy).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip

.PHONY: demo test test-fast lint docs bench clean

$(VENV)/.installed: setup.cfg pyproject.toml constraints-cpu.txt
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q -c constraints-cpu.txt torch==2.13.0 || $(PIP) install -q "torch>=2.1"
	$(PIP) install -q -c constraints-cpu.txt -e ".[tests,plots,docs,sweep,deploy,mpe,wandb]"
	touch $@

demo: $(VENV)/.installed
	$(PY) examples/demo.py

test: $(VENV)/.installed
	$(PY) -m pytest -q tests

test-fast: $(VENV)/.installed
	$(PY) -m pytest -q -m "not slow" tests

# mypy's settings (ignore_missing_imports, the package) are in pyproject.toml
lint: $(VENV)/.installed
	$(VENV)/bin/ruff check sb3_latentswarm tests examples benchmarks
	$(VENV)/bin/mypy

docs: $(VENV)/.installed
	$(VENV)/bin/sphinx-build -W --keep-going -b html docs docs/_build/html

bench: $(VENV)/.installed
	$(PY) benchmarks/env_throughput.py

clean:
	rm -rf $(VENV) docs/_build *.egg-info
