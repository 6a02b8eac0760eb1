# tacrom: `make demo` and `make test` do all set-up on a fresh machine (Rust and python3).
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip
LIB := target/release/libtacrom.so
PKG_LIB := python/tacrom/_lib/libtacrom.so
CARGO ?= cargo

.PHONY: all venv build demo test test-rust test-python bench bench-quick bench-micro stability clean

all: build

# Python environment with the pinned MuJoCo and ONNX Runtime wheels.
$(VENV)/.installed: python/requirements.txt
	python3 -m venv $(VENV)
	$(PIP) install -q -r python/requirements.txt
	touch $@

venv: $(VENV)/.installed

# The plugin library, copied into the Python package, which is installed (editable) so
# that `import mujoco` registers the plugin through its entry point.
$(VENV)/.tacrom-installed: $(VENV)/.installed python/pyproject.toml
	$(PIP) install -q --no-build-isolation --no-deps -e python
	touch $@

build: venv
	$(CARGO) build --release
	mkdir -p $(dir $(PKG_LIB))
	cp $(LIB) $(PKG_LIB)
	$(MAKE) --no-print-directory $(VENV)/.tacrom-installed

demo: build
	$(PY) examples/demo.py --out out/demo --physics rigid coarse

test-rust: venv
	$(CARGO) test --release

test-python: build
	$(PY) -m pytest tests/python -q

test: build test-rust test-python bench-quick

# The press benchmark (error against run time of every mode; README "Benchmarks").
bench: build
	$(CARGO) run --release --bin tacrom -- bench --full

bench-quick: venv
	$(CARGO) run --release --bin tacrom -- bench --quick

# Micro-benchmarks of one sensor evaluation per mode and indenter.
bench-micro: build
	$(CARGO) bench --bench sensor

# The stability suite's table.
stability: venv
	$(CARGO) run --release --bin tacrom -- stability

clean:
	rm -rf target out $(VENV) python/tacrom/_lib python/*.egg-info
