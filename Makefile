# Two entry points for a new user (see README): `make demo` (short train + evaluate) and `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip

.PHONY: demo test lint docs bench clean

$(VENV)/.installed: setup.cfg pyproject.toml constraints-cpu.txt
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q -c constraints-cpu.txt torch==2.13.0 || $(PIP) install -q "torch>=2.1"
	$(PIP) install -q -c constraints-cpu.txt -e ".[tests,plots,docs,sweep]"
	touch $@

demo: $(VENV)/.installed
	$(VENV)/bin/sb3-latentswarm train --preset demo --evaluate

test: $(VENV)/.installed
	$(PY) -m pytest -q tests

lint: $(VENV)/.installed
	$(VENV)/bin/ruff check sb3_latentswarm tests examples benchmarks

docs: $(VENV)/.installed
	$(VENV)/bin/sphinx-build -W --keep-going -b html docs docs/_build/html

bench: $(VENV)/.installed
	$(PY) benchmarks/env_throughput.py

clean:
	rm -rf $(VENV) docs/_build *.egg-info
