# Two commands a new user needs: `make demo` and `make test` (the fast tier; `make test-all`: everything, as CI).
# All create and reuse .venv.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PYTEST_ARGS ?=

.PHONY: demo test test-all bench lint install clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,report]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/python examples/demo.py --out out/demo

# The fast tier: every test not marked slow (a test over ~2 s on one core is marked `@pytest.mark.slow`).
test: $(STAMP)
	$(BIN)/python -m pytest -n auto --dist loadfile -m "not slow" $(PYTEST_ARGS)

# Everything, the slow tests and the real-data ones (skipped without ../shared/data/real-pairs) included.
test-all: $(STAMP)
	$(BIN)/python -m pytest -n auto --dist loadfile $(PYTEST_ARGS)

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	$(BIN)/python bench/run.py

lint: $(STAMP)
	$(BIN)/ruff check src tests examples experiments bench
	$(BIN)/ruff format --check src tests examples experiments bench

clean:
	rm -rf out build dist src/*.egg-info .pytest_cache .ruff_cache
