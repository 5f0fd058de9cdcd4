# Quick start: `make demo` and `make test`. Both create .venv and install the project on first use.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
EXTRAS ?= dev,rl,train

.PHONY: demo test test-slow lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[$(EXTRAS)]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/uav-struct study --out results --workers 2

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

lint: $(STAMP)
	$(BIN)/ruff check uav_struct_env localization tests benchmarks examples

bench: $(STAMP)  # every benchmark, on demand (minutes); figures are quoted in the README
	for b in render env_step localizer wrapper_throughput detector; do \
		[ -f benchmarks/$$b.py ] && $(BIN)/python benchmarks/$$b.py || exit 1; done

clean:
	rm -rf $(VENV) renders results
