# Every target creates .venv when missing and installs the project with its test extras.
# Idempotent: the install step re-runs only when pyproject.toml changes.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench lint clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/pmalab demo --out demo-output --force

test: $(STAMP)
	$(BIN)/ruff check pmalab tests bench
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python -m bench

lint: $(STAMP)
	$(BIN)/ruff check pmalab tests bench
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) demo-output .pytest_cache
