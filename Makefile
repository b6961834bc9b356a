# phri: the README's commands are targets here; CI (.ci/run) runs `make lint` and `make test`.
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
DEPS   := $(VENV)/.deps-installed
BUILT  := $(VENV)/.ext-built
CARGO_SOURCES := $(shell find crates -name '*.rs' -o -name Cargo.toml) Cargo.toml

.PHONY: help dev wheel docs demo test test-rust test-python lint bench bench-peers bench-trajopt-peers bench-trajopt-work bench-python bench-push bench-features bench-episode bench-variations clean

help:  ## List the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F ':.*## ' '{printf "  %-20s %s\n", $$1, $$2}'

$(PY):
	python3 -m venv $(VENV)

# Every extra's requirements (tests/test_package.py checks this list against pyproject.toml's extras).
$(DEPS): pyproject.toml | $(PY)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet "maturin>=1.9,<2" "ziglang>=0.13" "auditwheel>=6" "numpy>=1.24" "pytest>=8" \
		"pybullet>=3.2.6" "scipy>=1.11" "matplotlib>=3.8" "pandas>=2.1" "pyarrow>=14" "statsmodels>=0.14" \
		"tqdm>=4.66" "ray>=2.9" "pyyaml>=6" "hypothesis>=6.100" "ruff>=0.6" "mypy>=1.10" \
		"pylibfranka==0.21.3" "franky-sim==1.0.4" \
		"mkdocs>=1.6" "mkdocs-material>=9.5" "mkdocstrings-python>=1.16" "mkdocs-jupyter>=0.25" "ipykernel>=6" \
		"latex2mathml>=3.77" "markdown>=3.5"
	touch $@

# One release build of the extension serves both the editable install in .venv and the wheel in dist/:
# both link with zig (the ziglang package) against glibc 2.17 (manylinux2014) and build the stable-ABI
# extension (abi3, CPython >= 3.10; [tool.maturin] features), so cargo reuses the build for the wheel.
MATURIN_FLAGS := --zig --compatibility manylinux2014
WITH_ZIG      := PATH="$(abspath $(VENV))/bin:$$PATH"

$(BUILT): $(DEPS) $(CARGO_SOURCES) pyproject.toml
	rm -f python/phri/_phri.cpython-*.so  # a version-specific build would shadow the abi3 one
	$(WITH_ZIG) MATURIN_PEP517_ARGS="$(MATURIN_FLAGS)" \
		$(PIP) install --quiet --no-build-isolation --no-deps --editable .
	touch $@

dev: $(BUILT)  ## Create .venv, install dependencies, build and install phri (editable)

wheel: $(BUILT)  ## Build the abi3 manylinux2014 wheel into dist/ (reuses the build of `make dev`)
	rm -rf dist
	$(WITH_ZIG) $(VENV)/bin/maturin build --quiet --interpreter $(PY) $(MATURIN_FLAGS) --out dist

docs: $(BUILT)  ## Build the documentation site into site/ (strict: any warning fails)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir site

demo: $(BUILT)  ## Run the main job
	$(VENV)/bin/phri demo

test-rust:  ## Rust unit, integration and property tests
	cargo test --workspace

test-python: $(BUILT)  ## pytest (includes the PyBullet comparisons, the docs build and the wheel check)
	$(PY) -m pytest

test: test-rust test-python  ## Everything CI runs

lint: $(BUILT)  ## rustfmt, clippy, ruff, mypy, and the stub check
	cargo fmt --all --check
	cargo clippy --workspace --all-targets -- -D warnings
	$(VENV)/bin/ruff check python tests benches docs/*.py
	$(VENV)/bin/ruff format --check python tests benches docs/*.py
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

bench-push: $(BUILT)  ## Time a push's replan on the FR3's tasks, from the push to the adopted plan
	$(PY) benches/push_adoption.py

bench-features: $(BUILT)  ## Time cold plans with a feature declared or written in Python against the built-in
	$(PY) benches/user_features.py

bench-episode: $(BUILT)  ## Time simulated 15 s episodes against real time
	$(PY) benches/episode.py

bench-misspecified: $(BUILT)  ## The paper's update rule against "beta", on the study and with pushes no feature explains
	$(PY) benches/misspecified.py

bench-variations: $(BUILT)  ## The simulated person on 30 random variations of each task (a fresh seed; SEED=... to rerun)
	$(PY) benches/variations.py $(if $(SEED),--seed $(SEED))

clean:
	cargo clean
	rm -rf $(VENV) dist site python/phri/_phri*.so
