# haa_sym: every target installs what it needs into .venv (created on first use).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: all venv derive verify test test-slow browser check-generated paper bench bench-readme docs clean

all: verify

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,docs]'
	touch $(STAMP)

venv: $(STAMP)

## Regenerate generated/ from the symbolic model (byte-reproducible).
derive: $(STAMP)
	$(PY) -m codegen.generate --out generated

## Check the paper's equations (table of PASS/FAIL, non-zero exit on any FAIL).
verify: $(STAMP)
	$(PY) -m haa_sym.verify

## The main job: every figure and table of the paper and results/REPORT.md (~1 min).
paper: derive
	$(PY) -m haa_sym.cli reproduce --out results

## Speed: the full map against python-control and numpy baselines, haa_sym's own timings and the
## whole-process targets, the exact curves (prints tables; ~6 min). One JSON per script, with the
## machine, its load and the date, into $(BENCH_DIR) (default bench-results/, git-ignored).
BENCH_DIR ?= $(if $(HAA_SYM_BENCH_DIR),$(HAA_SYM_BENCH_DIR),bench-results)
bench: $(STAMP)
	HAA_SYM_BENCH_DIR=$(BENCH_DIR) $(PY) benchmarks/bench_baselines.py
	HAA_SYM_BENCH_DIR=$(BENCH_DIR) $(PY) benchmarks/bench_regions.py
	HAA_SYM_BENCH_DIR=$(BENCH_DIR) $(PY) benchmarks/bench_boundary.py
	HAA_SYM_BENCH_DIR=$(BENCH_DIR) $(PY) benchmarks/bench_schedule.py
	HAA_SYM_BENCH_DIR=$(BENCH_DIR) $(PY) benchmarks/bench_simulate.py
	HAA_SYM_BENCH_DIR=$(BENCH_DIR) $(PY) benchmarks/bench_nonlinear_map.py --cluster
	HAA_SYM_BENCH_DIR=$(BENCH_DIR) $(PY) benchmarks/bench_identify.py
	HAA_SYM_BENCH_DIR=$(BENCH_DIR) $(PY) benchmarks/bench_explore.py
	HAA_SYM_BENCH_DIR=$(BENCH_DIR) $(PY) benchmarks/bench_exact_passivity.py

## Rewrite the benchmark block of docs/benchmarks.md (between <!-- bench:start --> and
## <!-- bench:end -->) from the JSON of `make bench`; `make bench-readme BENCH_ARGS=--check` only compares.
bench-readme:
	$(PYTHON) benchmarks/render_readme.py --results $(BENCH_DIR) $(BENCH_ARGS)

## The documentation site from docs/ (Sphinx + myst-parser, the API from the numpydoc docstrings)
## into docs/_build/html; warnings are errors (CI runs it).
docs: $(STAMP)
	$(PY) -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "docs/_build/html/index.html"

## The test suite without the tests marked slow (under 2 min); `make test-slow` runs those.
## Two processes (pytest-xdist, tests handed out one by one): 83-91 s against 123-134 s in one on
## the shared 2-core machine (2026-11-26, load 1.6-3.2). The slow tests (clusters, ports, a
## browser) stay in one process.
## Bytecode is written (PYTHONDONTWRITEBYTECODE emptied for the tests only, into the gitignored
## __pycache__/ of the checkout): with it set, as on the CI machines, every xdist worker and every
## subprocess a test starts compiled haa_sym and the tests again (collection 10.1 -> 4.2 CPU s per
## process, `import haa_sym.cli` in a subprocess 1.1 -> 0.63 s).
TEST_ENV = PYTHONDONTWRITEBYTECODE=
test: $(STAMP)
	$(TEST_ENV) $(PY) -m pytest -q -m "not slow" -n 2 $(PYTEST_ARGS)

## The tests marked slow (a wheel, C libraries, a dask cluster, the quick reproduction, the
## explorer in headless chromium, ...).
test-slow: $(STAMP) browser
	$(TEST_ENV) $(PY) -m pytest -q -m slow $(PYTEST_ARGS)

## Debian's chromium for tests/test_explore_browser.py (playwright drives /usr/bin/chromium; its
## own browser download is not used). Installs it with apt-get when missing (as root).
browser:
	@command -v chromium >/dev/null 2>&1 && echo "chromium: $$(command -v chromium)" || { \
	  if [ "$$(id -u)" = 0 ]; then apt-get update && apt-get install -y chromium; \
	  else echo "chromium is missing: run \`sudo apt-get update && sudo apt-get install -y chromium\` (Debian/Ubuntu) and retry"; exit 1; fi; }

## Fail if `make derive` would change generated/.
check-generated: $(STAMP)
	@tmp=$$(mktemp -d) && $(PY) -m codegen.generate --out $$tmp >/dev/null && \
	  diff -r $$tmp generated >/dev/null || { echo "generated/ is stale: run \`make derive\`"; exit 1; }; \
	  echo "generated/ is up to date"

clean:
	rm -rf $(VENV) build src/*.egg-info docs/_build
