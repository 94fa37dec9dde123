# CMM error lab: `make run` starts the app on the sample data, `make test` installs and tests.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
PORT ?= 8501
# exact versions of everything installed (made by `make lock` from the requirements files)
LOCK := requirements-lock.txt
TEST_LOCK := requirements-test-lock.txt
COMPILE = $(BIN)/pip-compile -q --strip-extras --allow-unsafe --no-emit-index-url --no-emit-find-links

.PHONY: run test test-fast lint bench clean lock

$(BIN)/python:
	$(PY) -m venv $(VENV)

# the package itself too (editable): `.venv/bin/cmm-error-lab` runs the CLI from anywhere
$(VENV)/.runtime: $(LOCK) pyproject.toml setup.py | $(BIN)/python
	$(BIN)/pip install -q -r $(LOCK)
	$(BIN)/pip install -q --no-deps -e .
	touch $@

$(VENV)/.test: $(TEST_LOCK) pyproject.toml setup.py | $(BIN)/python
	$(BIN)/pip install -q -r $(TEST_LOCK)
	$(BIN)/pip install -q --no-deps -e .
	touch $@

# the same as an installed `cmm-error-lab app`: on this computer only, HOST=0.0.0.0 for the network
HOST ?= 127.0.0.1
run: $(VENV)/.runtime
	$(BIN)/cmm-error-lab app --port $(PORT) --host $(HOST)

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

# after a change of requirements.txt or requirements-test.txt: new exact versions
lock: | $(BIN)/python
	$(BIN)/pip install -q pip-tools
	$(COMPILE) --output-file $(LOCK) requirements.txt
	$(COMPILE) --output-file $(TEST_LOCK) requirements-test.txt

clean:
	rm -rf $(VENV) .pytest_cache tests/artifacts
