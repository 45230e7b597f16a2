# Two entry points do all set-up on a fresh machine (README): `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench setup clean

setup: $(STAMP)

# torch is installed first and pinned so that pip never resolves a CUDA build on a CPU machine.
$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e '.[dev]'
	$(BIN)/flightrecon build-ext
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/flightrecon fly scenarios/demo.toml

test: $(STAMP)
	$(BIN)/python -m pytest -q tests

bench: $(STAMP)
	$(BIN)/flightrecon bench all

clean:
	rm -rf $(VENV) build .cache
