# Two commands do everything on a fresh Debian machine with Python 3.11:
#   make demo   -- set up .venv, install stratamap, run configs/demo.yaml into out/demo/
#   make test   -- set up .venv, install stratamap with test extras, run the test suite
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.stratamap-installed
OUT ?= out/demo

.PHONY: demo test install system-deps bench clean

demo: $(STAMP)
	$(VENV)/bin/stratamap demo --out $(OUT)

test: $(STAMP)
	$(PY) -m pytest -q

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

clean:
	rm -rf $(VENV) out build *.egg-info
