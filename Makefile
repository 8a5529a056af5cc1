# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
CORE   := $(VENV)/.installed-core
STAMP  := $(VENV)/.installed

.PHONY: fuzz venv demo test test-portable lint bench bench-ref bench-full clean

venv: $(STAMP)

# Packages go in with uv (itself a PyPI wheel; MIT/Apache-2.0), which fetches and unpacks the wheels in parallel:
# the core install took 11 s against pip's 27 s on the 2-core VM, cold caches (docs/benchmarks.md, "Time to first
# result"). uv does not read pip's settings: the index, extra index, find-links and CA bundle given to pip in the
# environment are passed on, and uv also trusts the system's certificates. Files
# are hard-linked from uv's cache where it is on the same filesystem (uv's default; a copy otherwise): 3.9–4.0 s
# against 4.4–5.6 s copying, cold cache. Where uv cannot be installed or fails, pip does the same install.
UV_ENV = export UV_SYSTEM_CERTS=1; \
	[ -z "$${PIP_INDEX_URL:-}" ] || export UV_INDEX_URL="$$PIP_INDEX_URL"; \
	[ -z "$${PIP_EXTRA_INDEX_URL:-}" ] || export UV_EXTRA_INDEX_URL="$$PIP_EXTRA_INDEX_URL"; \
	[ -z "$${PIP_FIND_LINKS:-}" ] || export UV_FIND_LINKS="$$PIP_FIND_LINKS"; \
	[ -z "$${PIP_CERT:-}" ] || export SSL_CERT_FILE="$$PIP_CERT"
INSTALL = $(UV_ENV); if [ -x $(BIN)/uv ] && $(BIN)/uv pip install --quiet --python $(BIN)/python -e '$(1)' pip; \
	then :; else { $(BIN)/python -m pip --version >/dev/null 2>&1 || $(BIN)/python -m ensurepip --upgrade --default-pip; } \
	&& $(BIN)/python -m pip install --quiet --upgrade pip && $(BIN)/python -m pip install --quiet -e '$(1)'; fi

# The venv is created without pip (`python -m venv` spends 3.6 s of the 2-core Intel VM installing and byte-compiling
# pip) and uv's binary is fetched by the system's pip into a scratch folder (`--target`: nothing is installed into
# the system's Python; uv has no dependencies and only its binary is kept: 1.9–2.1 s against 2.9–3.3 s with pip's
# dependency check and byte-compiling); uv then puts pip into the venv with everything else. Without a system pip,
# the venv's own (ensurepip) installs uv, as before.
GET_UV = $(UV_ENV); [ -x $(BIN)/uv ] || { $(PYTHON) -m pip install --quiet --disable-pip-version-check --no-deps \
	--no-compile --target $(VENV)/.uv-bootstrap uv >/dev/null 2>&1 && cp $(VENV)/.uv-bootstrap/bin/uv $(BIN)/uv; \
	rm -rf $(VENV)/.uv-bootstrap; [ -x $(BIN)/uv ]; } || { $(BIN)/python -m ensurepip --upgrade --default-pip \
	>/dev/null && $(BIN)/python -m pip install --quiet uv; } || echo "make: uv not available, installing with pip"

# what a run needs (idp and CHOLMOD): enough for `make demo`, and about half the install time of everything
$(CORE): pyproject.toml
	@echo "make: creating $(VENV) and installing idp with its dependencies (first time only, about 10 s)"
	$(PYTHON) -m venv --without-pip $(VENV)
	@echo "installing uv into $(VENV) (pip if that fails)"
	@$(GET_UV)
	@echo "uv pip install -e '.[cholmod]' (pip if uv fails)"
	@$(call INSTALL,.[cholmod])
	@# as installing wheels does, but only for idp and what a run imports (make test's install compiles the rest)
	$(BIN)/python -m idp._bytecode
	touch $(CORE)

# everything: tests, static checks and the optional extras (USD, remeshing, Dask batches)
# (a variable: a literal comma would split $(call)'s argument)
ALL_EXTRAS := cholmod,test,lint,usd,remesh,batch
$(STAMP): $(CORE)
	@echo "make: installing the test, lint and optional extras into $(VENV) (first time only)"
	@echo "uv pip install -e '.[$(ALL_EXTRAS)]' (pip if uv fails)"
	@$(call INSTALL,.[$(ALL_EXTRAS)])
	@# byte-compiles what the first install left (uv's --compile-bytecode only reaches the packages it installs)
	$(BIN)/python -m compileall -q -j 0 -x '/tests?/' "$$($(BIN)/python -c 'import sysconfig; print(sysconfig.get_path("purelib"))')" >/dev/null || true
	touch $(STAMP)

# the first run on a machine compiles the numba kernels (about half a minute on 2 cores, shown as a progress bar);
# later runs load them from numba's cache in idp/**/__pycache__
demo: $(CORE)
	$(BIN)/idp demo -o out/demo

# the suite on up to 4 worker processes (pytest-xdist), each taking a whole test file at a time (a module's fixtures
# stay in one process): 414 s against 753 s in one process on the 2-core AMD EPYC VM (docs/benchmarks.md, "Test
# suite time"). TEST_WORKERS=0 runs it in this process.
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); [ $$n -gt 4 ] && n=4; echo $$n)
PARALLEL = -n $(TEST_WORKERS) --dist loadfile

test: $(STAMP)
	$(BIN)/python -m pytest -q $(PARALLEL)

# The tests that run compiled (numba) kernels, once on baseline code paths — numba compiling for its generic
# x86-64 CPU (no FMA/AVX), OpenBLAS's Nehalem kernels and numpy's baseline loops (their exp/log/power differ
# in the last bits from the AVX-512 ones) — and once single-threaded (each worker process): results must not
# depend on the CPU or the thread count. numba's disk cache is keyed by CPU name, so the first run recompiles every kernel.
PORTABLE_TESTS := tests/contact tests/energies tests/solver tests/stepper tests/mesh

test-portable: $(STAMP)
	features="$$($(BIN)/python .ci/numpy_dispatched_features.py)" && \
	NUMBA_CPU_NAME=generic OPENBLAS_CORETYPE=Nehalem NPY_DISABLE_CPU_FEATURES="$$features" \
	$(BIN)/python -m pytest -q $(PARALLEL) $(PORTABLE_TESTS)
	NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 \
	$(BIN)/python -m pytest -q $(PARALLEL) $(PORTABLE_TESTS)

# A longer bug hunt than make test's fixed draws: new random inputs on every run (not in CI, which must pass or
# fail the same way on every clean clone); pin what it finds as a regression test in tests/fuzz.
fuzz: $(STAMP)
	IDP_FUZZ_RANDOM=1 IDP_FUZZ_SCALE=$${IDP_FUZZ_SCALE:-10} $(BIN)/python -m pytest -q tests/fuzz

# Static checks (also run by .ci/run and, per commit, by .pre-commit-config.yaml)
LINT_PATHS := idp bench tests

lint: $(STAMP)
	$(BIN)/ruff check $(LINT_PATHS)
	$(BIN)/ruff format --check $(LINT_PATHS)
	$(BIN)/mypy $(LINT_PATHS)

bench: $(STAMP)
	$(BIN)/idp bench --quick -o bench/results/quick

bench-ref: $(STAMP)
	$(BIN)/idp bench --quick --with-reference -o bench/results/with-reference

bench-full: $(STAMP)
	$(BIN)/idp bench -o bench/results/full

clean:
	rm -rf out bench/results $(VENV)
