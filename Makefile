# Two commands do all the set-up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
DEMO   := demo

.PHONY: demo test lint bench bench-doc fuzz sysdeps check-python clean

# Headless OpenGL: Mesa's EGL renders on the CPU; OSMesa is the fallback. Installed only when
# missing and only where apt-get can run (as root); otherwise the renderer says what is missing.
sysdeps:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa.so\|libOSMesa.so'; then \
	  if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	    echo "installing Mesa (EGL/OSMesa) for headless rendering"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	      libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libosmesa6 >/dev/null; \
	  else \
	    echo "warning: no Mesa EGL/OSMesa found; install libegl-mesa0 or libosmesa6" >&2; \
	  fi; \
	fi

# The venv is made once, by $(PYTHON), which must meet pyproject's requires-python: one below it
# made a venv that pip then refused to install aslam into, and every later `make`, whatever
# PYTHON it was given, went on with that venv and failed the same way. A PYTHON given on the
# command line or in the environment must also be the existing venv's X.Y: `make test
# PYTHON=python3.12` over a venv of 3.11 ran 3.11 in silence. Checked before anything is made.
REQUIRES_PYTHON := $(shell sed -n 's/^requires-python = ">=\([0-9.]*\)"$$/\1/p' pyproject.toml)
PYTHON_GIVEN := $(if $(filter file,$(origin PYTHON)),,given)
define CHECK_PYTHON
import os, sys
floor, venv, python, given = sys.argv[1:]
have = "%d.%d" % sys.version_info[:2]
if sys.version_info[:2] < tuple(int(part) for part in floor.split(".")):
    sys.exit("aslam needs Python >= %s; PYTHON=%s is %s" % (floor, python, have))
config = os.path.join(venv, "pyvenv.cfg")
made = have
if given and os.path.exists(config):
    for line in open(config):
        key, _, value = line.partition("=")
        if key.strip() == "version":
            made = value.strip()
if ".".join(made.split(".")[:2]) != have:
    sys.exit("%s was made with Python %s, not PYTHON=%s (%s): `make clean` removes it,"
             " or VENV=DIR gives this Python a venv of its own" % (venv, made, python, have))
endef
export CHECK_PYTHON

check-python:
	@$(PYTHON) -c "$$CHECK_PYTHON" '$(REQUIRES_PYTHON)' '$(VENV)' '$(PYTHON)' '$(PYTHON_GIVEN)'

$(BIN)/python: | check-python
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# pyrender pins PyOpenGL 3.1.0, whose OSMesa binding is too old for pyrender's own OSMesa code;
# 3.1.10 serves EGL and OSMesa alike, so it replaces the pin (pip would refuse it as a dependency).
# pip puts 3.1.0 back whenever it installs aslam's dependencies again: in the rules below, and in a
# `pip install -e .` by hand after them, which no sentinel file sees (`make test` then ran on 3.1.0);
# so every target that runs aslam checks it too (one Python start when it is right).
PYOPENGL := 3.1.10
PIN_PYOPENGL := $(BIN)/python -c "import importlib.metadata as m; raise SystemExit(m.version('PyOpenGL') != '$(PYOPENGL)')" 2>/dev/null \
	|| { echo "PyOpenGL $(PYOPENGL) over pyrender's pin"; $(BIN)/python -m pip install -q --no-deps 'PyOpenGL==$(PYOPENGL)'; }

# An editable install leaves our modules uncompiled; with PYTHONDONTWRITEBYTECODE set (as in many
# CI images) every run would compile them again (0.1 s of each command's start-up).
BYTECODE := $(BIN)/python -m compileall -q app cli core data_formats recorder

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e .
	@$(PIN_PYOPENGL)
	$(BYTECODE)
	touch $@

$(VENV)/.dev-installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[dev]'
	@$(PIN_PYOPENGL)
	$(BYTECODE)
	touch $@ $(VENV)/.installed

$(VENV)/.bench-installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[bench]'
	@$(PIN_PYOPENGL)
	$(BYTECODE)
	touch $@ $(VENV)/.installed

demo: sysdeps $(VENV)/.installed
	@$(PIN_PYOPENGL)
	@mkdir -p $(DEMO)
	$(BIN)/aslam record --route paper -o $(DEMO)/paper.mcap --force --contact-sheet $(DEMO)/contact-sheet.png
	$(BIN)/aslam estimate $(DEMO)/paper.mcap -o $(DEMO)/estimate.mcap --force
	$(BIN)/aslam report $(DEMO)/estimate.mcap --force --graph $(DEMO)/graph.json --plots $(DEMO)/plots --json $(DEMO)/summary.json

# mypy finds the package by its folder's name, `aslam`, and a clone may be called anything: it runs
# in a folder of the venv holding a link named aslam to the clone, its cache beside it (about 25 s
# the first time, under a second after). It is given pyproject's subpackages by name and
# __main__: `-p aslam` walked every folder of the clone, and a venv in the clone named as a package
# may be (VENV=venv312) led it back through the link, for ever. Paths reach the shell quoted (a
# clone in "My Projects"), and mypy runs as the venv's `python -m mypy`, which a moved venv still
# runs (its scripts' first lines name the old place).
MYPY_PACKAGES := $(filter-out aslam,$(shell sed -n 's/^packages = \[\(.*\)\]$$/\1/p' pyproject.toml | tr -d '",'))
MYPY = clone="$$(pwd)" && venv="$$(cd '$(VENV)' && pwd)" && mkdir -p "$$venv/mypy" \
	&& ln -sfn "$$clone" "$$venv/mypy/aslam" && cd "$$venv/mypy" \
	&& "$$venv/bin/python" -m mypy --config-file "$$clone/pyproject.toml" --cache-dir cache \
	-m aslam.__main__ $(MYPY_PACKAGES:%=-p %)

test: sysdeps $(VENV)/.dev-installed
	@$(PIN_PYOPENGL)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(MYPY)
	$(BIN)/pytest -q

lint: $(VENV)/.dev-installed
	$(BIN)/ruff check --fix .
	$(BIN)/ruff format .
	$(MYPY)

# Measures (~7 min, both cores), writes bench/results/benchmarks.json, then renders the document.
bench: sysdeps $(VENV)/.bench-installed
	@$(PIN_PYOPENGL)
	@$(BYTECODE)  # modules edited since the install: else each estimate measured compiles them again
	$(BIN)/python bench/run_all.py

# Only docs/benchmarks.md and its plot again from bench/results/benchmarks.json (seconds): for wording.
bench-doc: $(VENV)/.bench-installed
	$(BIN)/python bench/render.py

# The long fuzz (docs/reliability.md): hostile recordings, estimate files, routes and options
# through the CLI, every case checked against the error contract. Niced: the machine may be shared.
FUZZ_CASES ?= 10000
fuzz: $(VENV)/.dev-installed
	@$(PIN_PYOPENGL)
	nice -n 10 $(BIN)/python tests/fuzz.py $(FUZZ_CASES) --json fuzz-summary.json

clean:
	rm -rf $(VENV) $(DEMO) build dist *.egg-info .pytest_cache .ruff_cache
