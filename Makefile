# Two commands do all set-up: `make run` and `make test` (both create .venv on first use).
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export YOLO_OFFLINE := 1
export YOLO_AUTOINSTALL := 0
export YOLO_VERBOSE := 0
export YOLO_CONFIG_DIR := $(CURDIR)/.yolo
export MPLBACKEND := Agg

.PHONY: run test test-all bench perceive-bench clean-venv

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# torch and torchvision must be this pair (both come from local disk here)
	$(BIN)/python -m pip install --quiet "torch==2.14.1" "torchvision==0.29.1"
	$(BIN)/python -m pip install --quiet -e ".[dev,distributed]"
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/shelfpick console --source demo

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -m ""

clean-venv:
	rm -rf $(VENV)
