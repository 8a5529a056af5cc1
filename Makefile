# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: venv demo test bench bench-full clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[cholmod,test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/idp demo -o out/demo

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/idp bench --quick -o bench/results/quick

bench-full: $(STAMP)
	$(BIN)/idp bench -o bench/results/full

clean:
	rm -rf out bench/results $(VENV)
