# phri: the README's commands are targets here; CI (.ci/run) runs `make lint` and `make test`.
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
DEPS   := $(VENV)/.deps-installed
BUILT  := $(VENV)/.ext-built
CARGO_SOURCES := $(shell find crates -name '*.rs' -o -name Cargo.toml) Cargo.toml

.PHONY: help dev demo test test-rust test-python lint bench bench-peers bench-trajopt-peers bench-trajopt-work bench-python bench-episode clean

help:  ## List the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F ':.*## ' '{printf "  %-20s %s\n", $$1, $$2}'

$(PY):
	python3 -m venv $(VENV)

$(DEPS): pyproject.toml | $(PY)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet "maturin>=1.9,<2" "numpy>=1.24" "pytest>=8" "pybullet>=3.2.6" "scipy>=1.11" \
		"matplotlib>=3.8" "pandas>=2.1" "pyarrow>=14" "statsmodels>=0.14" "tqdm>=4.66" "ray>=2.9" \
		"pyyaml>=6" "hypothesis>=6.100" "ruff>=0.6" "mypy>=1.10" \
		"pylibfranka==0.21.3" "franky-sim==1.0.4"
	touch $@

$(BUILT): $(DEPS) $(CARGO_SOURCES) pyproject.toml
	VIRTUAL_ENV=$(abspath $(VENV)) $(VENV)/bin/maturin develop --release --quiet
	touch $@

dev: $(BUILT)  ## Create .venv, install dependencies, build and install phri (editable)

demo: $(BUILT)  ## Run the main job
	$(VENV)/bin/phri demo

test-rust:  ## Rust unit, integration and property tests
	cargo test --workspace

test-python: $(BUILT)  ## pytest (includes the PyBullet comparisons)
	$(PY) -m pytest

test: test-rust test-python  ## Everything CI runs

lint: $(BUILT)  ## rustfmt, clippy, ruff, mypy, and the stub check
	cargo fmt --all --check
	cargo clippy --workspace --all-targets -- -D warnings
	$(VENV)/bin/ruff check python tests benches
	$(VENV)/bin/ruff format --check python tests benches
	$(PY) -m mypy python/phri
	$(PY) -m mypy.stubtest phri._phri --allowlist .stubtest-allowlist

bench:  ## Criterion benchmarks (median and worst case)
	cargo bench -p phri_benches

bench-peers: $(BUILT)  ## Time phri against pinocchio and PyBullet side by side
	$(PIP) install --quiet "pin>=3"
	$(PY) benches/peers.py

bench-trajopt-peers: $(BUILT)  ## Time phri's trajectory optimiser against scipy L-BFGS-B and Drake
	$(PIP) install --quiet "pin>=3" "scipy>=1.11"
	$(PIP) install --quiet drake || echo "drake did not install here: its rows are skipped"
	$(PY) benches/trajopt_peers.py

bench-trajopt-work:  ## Instructions per cold plan, N = 100 against N = 31 (callgrind; needs valgrind)
	python3 benches/trajopt_work.py

bench-python: $(BUILT)  ## Time the per-tick calls of a 1 kHz loop written in Python
	$(PY) benches/python_step.py

bench-episode: $(BUILT)  ## Time simulated 15 s episodes against real time
	$(PY) benches/episode.py

clean:
	cargo clean
	rm -rf $(VENV)
