# spectral-rig — two commands on a fresh clone: `make demo` and `make test`.
PYTHON ?= python3
# Python may cache its compiled modules here (__pycache__, ignored by git) even where the environment
# says not to: every test process, pool worker and command-line child would otherwise compile the
# project's modules again (about a tenth of the default suite's time).
unexport PYTHONDONTWRITEBYTECODE
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
DEMO_DIR ?= demo-output

.PHONY: install demo test test-all tests-default tests-all checks lint typecheck docs format bench clean

SIM_STAMP := $(VENV)/.sim-stamp

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

# The demo needs the twin's libraries ([sim]), not the development tools.
$(SIM_STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[sim]'
	touch $(SIM_STAMP)

install: $(STAMP)

## A full simulated capture on the digital twin, then the estimate and its report.
demo: $(SIM_STAMP)
	$(BIN)/rig demo --out $(DEMO_DIR)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy

## The documentation site (mkdocs.yml) into build/site; any warning fails the build. Offline.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

# The static checks side by side (mypy is one process; the docs build another), each target's
# output kept together.
checks: $(STAMP)
	$(MAKE) --no-print-directory -j2 --output-sync=target lint typecheck docs

# The default tests (pytest-xdist's two workers) and the static checks run side by side: mypy's
# single process fills the cores while tests wait on their subprocesses and timeouts. Any failure
# fails the target; each part's output is printed whole when it ends.
tests-default: $(STAMP)
	$(BIN)/pytest -n 2 -q

tests-all: $(STAMP)
	$(BIN)/pytest -n 2 -q -m ''

## The default suite: lint, types, the docs build, and every test not marked slow.
test: $(STAMP)
	$(MAKE) --no-print-directory -j4 --output-sync=line lint typecheck docs tests-default

## Everything, slow tests included.
test-all: $(STAMP)
	$(MAKE) --no-print-directory -j4 --output-sync=line lint typecheck docs tests-all

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

bench: $(STAMP)
	@for script in bench/*.py; do echo "== $$script"; $(BIN)/python $$script || exit 1; done

clean:
	rm -rf $(VENV) $(DEMO_DIR) .mypy_cache .ruff_cache build *.egg-info
