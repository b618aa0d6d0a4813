# Two commands do everything on a fresh Debian machine with Python 3.11:
#   make demo   -- set up .venv, install stratamap, run configs/demo.yaml into out/demo/
#   make test   -- set up .venv, install stratamap with test extras, run the whole test suite (CI)
# and, while working on stratamap:
#   make test-fast -- the suite without the tests marked slow (whole-pipeline runs): under 2 minutes
#   make lint      -- ruff lint and format checks (the suite runs them too)
#   make format    -- apply ruff's fixes and formatting
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.stratamap-installed
BROWSER_STAMP := $(VENV)/.stratamap-browser
OUT ?= out/demo
# Test files run on this many processes side by side (pytest-xdist; a file's tests stay together,
# so its shared fixtures run once). The whole suite takes three: its slow tests often wait on
# subprocesses, Ray and a browser, and a third process fills that time (on 2 cores, 10 min 25 s
# with two, 8 min 54 s with three). The fast tests keep the cores busy: two (1 min 50 s, 1 min 57 s
# with three).
TEST_WORKERS ?= 3
TEST_FAST_WORKERS ?= 2
PYTEST_ARGS := -q --dist loadfile
# One BLAS thread per test process: the processes already fill every core, and OpenBLAS's extra
# threads only spin between small matrix calls (on 2 cores the whole suite took 24 CPU-minutes
# with them, 20 without; `make test` 12 min 14 s -> 10 min 23 s).
# Bytecode is cached even where the shell sets PYTHONDONTWRITEBYTECODE (some CI images do): without
# the cache every test process, and every `stratamap` subprocess a test starts, compiles the whole
# package and pytest rewrites every test module again (collecting the fast suite: 7.6-8.3 s of CPU
# per process without the cache, 5.0 s with it; docs/experiments/2026-12-07-suite-bytecode-cache.md).
TEST_ENV := env -u PYTHONDONTWRITEBYTECODE OPENBLAS_NUM_THREADS=1

.PHONY: demo test test-fast lint format install system-deps clean

demo: $(STAMP)
	$(VENV)/bin/stratamap demo --out $(OUT)

test: $(STAMP) $(BROWSER_STAMP)
	$(TEST_ENV) $(PY) -m pytest $(PYTEST_ARGS) -n $(TEST_WORKERS)

test-fast: $(STAMP)
	$(TEST_ENV) $(PY) -m pytest $(PYTEST_ARGS) -n $(TEST_FAST_WORKERS) -m "not slow"

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

format: $(STAMP)
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

install: $(STAMP)

system-deps:
	bash scripts/system-deps.sh

$(PY):
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml scripts/system-deps.sh | $(PY)
	bash scripts/system-deps.sh
	$(PIP) install -q --upgrade pip setuptools wheel
	$(PIP) install -q -e ".[test]"
	touch $(STAMP)

# The browser tests drive Debian's chromium (installed here, once).
$(BROWSER_STAMP): scripts/system-deps.sh | $(STAMP)
	bash scripts/system-deps.sh --browser
	touch $(BROWSER_STAMP)

clean:
	rm -rf $(VENV) out build *.egg-info
