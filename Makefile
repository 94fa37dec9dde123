# CMM error lab: `make run` starts the app on the sample data, `make test` installs and tests.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
PORT ?= 8501

.PHONY: run test test-fast lint bench clean

$(BIN)/python:
	$(PY) -m venv $(VENV)

# the package itself too (editable): `.venv/bin/cmm-error-lab` runs the CLI from anywhere
$(VENV)/.runtime: requirements.txt pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q -r requirements.txt
	$(BIN)/pip install -q --no-deps -e .
	touch $@

$(VENV)/.test: requirements.txt requirements-test.txt pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q -r requirements-test.txt
	$(BIN)/pip install -q --no-deps -e .
	touch $@

run: $(VENV)/.runtime
	$(BIN)/python serve.py --server.port $(PORT) --server.headless true

test: $(VENV)/.test
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/python -m pytest -q tests

test-fast: $(VENV)/.test
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/python -m pytest -q tests -m "not slow"

lint: $(VENV)/.test
	$(BIN)/ruff check .

bench: $(VENV)/.test
	for f in bench/*.py; do echo "== $$f ($$(date +%T))"; $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) .pytest_cache tests/artifacts
