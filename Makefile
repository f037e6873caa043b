# Two commands on a fresh machine: `make run` (the paper, reproduced into runs/paper/report.md) and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test test-slow bench clean osmesa compiler

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	@touch $(STAMP)

run: $(STAMP) osmesa compiler
	$(BIN)/mjxcpg reproduce --config paper --out runs/paper

test: $(STAMP) osmesa compiler
	$(BIN)/pytest -q

test-slow: $(STAMP)
	$(BIN)/pytest -q -m slow

bench: $(STAMP)
	$(BIN)/mjxcpg bench

# Headless OpenGL for `mjxcpg render` (MUJOCO_GL=osmesa on machines without a GPU). A failed
# install is a warning: only rendering needs it.
osmesa:
	@ldconfig -p 2>/dev/null | grep -q libOSMesa || { \
	  command -v apt-get >/dev/null && \
	  { apt-get install -y -qq libosmesa6 >/dev/null 2>&1 || \
	    { apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq libosmesa6 >/dev/null 2>&1; }; } || \
	  echo "warning: could not install libosmesa6; 'mjxcpg render' needs OSMesa or a GPU with EGL" >&2; }

# A C++ compiler builds the native engine's MuJoCo step inside XLA (mjxcpg/physics/native_step.py)
# on first use. A failed install is a warning: without it MuJoCo runs through a Python
# callback, with the same results, slower at small batches.
compiler:
	@command -v c++ >/dev/null || command -v g++ >/dev/null || { \
	  command -v apt-get >/dev/null && \
	  { apt-get install -y -qq g++ >/dev/null 2>&1 || \
	    { apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq g++ >/dev/null 2>&1; }; } || \
	  echo "warning: could not install g++; the native engine steps MuJoCo through a Python callback (slower at small batches)" >&2; }

clean:
	rm -rf $(VENV) .pytest_cache
