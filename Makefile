# Two commands on a fresh machine with Python 3.11 and pip: `make demo`, `make test`.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DOCS_STAMP := $(VENV)/.installed-docs
DEMO   ?= demo

.PHONY: demo test test-isa soak bench papers docs clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV) || python3 -m venv $(VENV)

# --no-compile, then tools/compile_imported.py: bytecode for what jaxpile and its tests import, not for
# all of jax-md's requirements (half of pip's time; docs/choices.md#the-install)
$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --no-compile -e ".[test]"
	$(BIN)/python tools/compile_imported.py
	touch $(STAMP)

$(DOCS_STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --no-compile -e ".[docs]"
	$(BIN)/python tools/compile_imported.py
	touch $(DOCS_STAMP)

# The main job: the 1992 equilateral pile (45 layers, 1035 disks) relaxed with the hooke
# law and checked against eqs. 42 and 44; the same pile with disk-disk friction
# (mu = 0.1), whose base forces depend on how the pile was loaded; and the pile with
# the paper's own law (viscous friction, static well at the ground).
demo: $(STAMP)
	$(BIN)/jaxpile pile --protocol lattice --layers 45 --law hooke --out $(DEMO)/lattice
	$(BIN)/jaxpile pile --protocol lattice --layers 45 --law hooke --set mu=0.1 --out $(DEMO)/lattice_mu0.1
	$(BIN)/jaxpile pile --protocol lattice --layers 45 --law liffman --out $(DEMO)/lattice_liffman
	$(BIN)/jaxpile compare $(DEMO)/lattice $(DEMO)/lattice_mu0.1 $(DEMO)/lattice_liffman

# Test workers: one per core, at most 4 (each holds its own JAX compile cache).
JOBS ?= $(shell n=$$(nproc 2>/dev/null || echo 2); [ $$n -gt 4 ] && n=4; echo $$n)

# Each module (or test class) on one worker, the costliest first (tests/conftest.py).
test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(JOBS) --dist loadscope --no-loadscope-reorder

# The suite as CPUs with other instruction sets run it: XLA compiles here the code it would compile
# there (--xla_cpu_max_isa), which differs at round-off, as another CPU's does. One full suite per
# level, one after another (docs/testing.md#on-any-cpu). ISAS="AVX AVX512" picks others.
ISAS ?= SSE4_2 AVX2
test-isa: $(STAMP)
	@for isa in $(ISAS); do \
		echo "== make test with XLA_FLAGS=--xla_cpu_max_isa=$$isa"; \
		XLA_FLAGS="$$XLA_FLAGS --xla_cpu_max_isa=$$isa" $(BIN)/python -m pytest -q -n $(JOBS) --dist loadscope \
			--no-loadscope-reorder || exit 1; \
	done

# The long correctness checks `make test` leaves out (tests marked soak): a pour killed and
# resumed against the uninterrupted one (tests/test_soak.py), every protocol with every law and
# every protocol's sweep under the commands' XLA settings (tests/test_protocol_law_matrix.py).
soak: $(STAMP)
	$(BIN)/python -m pytest -q -m soak

# The documentation site (mkdocs.yml: MkDocs Material, the API from the docstrings, the notebooks as
# tutorials) built into site/, warnings as errors. tests/test_docs.py builds it in `make test` too.
docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict --site-dir site

# Benchmarks (about 10 minutes on 2 CPU cores; LAMMPS `lmp` is raced when installed):
# JSON in benchmarks/results/<backend>/, docs/performance.md's table regenerated. BENCH=--full for full sizes.
bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py $(BENCH)

# The papers' numbers as ensembles (hours on 2 CPU cores; resumable: rerun to continue), then
# docs/papers.md's table from benchmarks/results/. PAPERS=--only=lattice,tilt picks studies.
papers: $(STAMP)
	$(BIN)/python benchmarks/studies/papers/papers.py --run $(PAPERS)

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache site
