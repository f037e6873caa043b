# Two commands on a fresh machine: `make run` (the paper's sweep) and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test test-slow bench clean osmesa

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	@touch $(STAMP)

run: $(STAMP) osmesa
	$(BIN)/mjxcpg sweep --config paper --out runs/paper --resume

test: $(STAMP) osmesa
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

clean:
	rm -rf $(VENV) .pytest_cache
