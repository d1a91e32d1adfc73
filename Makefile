# Two commands do all set-up: `make run` and `make test` (both create .venv on first use).
# `make run` installs what the console needs (`.[console]`: no torch, ~0.9 GB); `make test` adds
# every extra and the dev tools (`.[all,dev]`, torch and its CUDA libraries: ~7 GB).
PY ?= python3.11
# no wheel cache: `make test` installs ~7.2 GB (torch's CUDA libraries alone 4 GB), and a cache would
# keep a second copy of every wheel fetched from PyPI (CI ran out of disk once, at the torch step)
PIP_FLAGS := --quiet --no-cache-dir
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
RUN_STAMP := $(VENV)/.installed-run
export YOLO_OFFLINE := 1
export YOLO_AUTOINSTALL := 0
export YOLO_VERBOSE := 0
export YOLO_CONFIG_DIR := $(CURDIR)/.yolo
export MPLBACKEND := Agg

# the browser tests drive Debian's chromium (tests/console/test_browser.py); BROWSER_TESTS=0 leaves them out
CHROMIUM := /usr/bin/chromium
BROWSER_TESTS ?= 1
ifeq ($(BROWSER_TESTS),0)
BROWSER_DEPS :=
TEST_MARKS := not slow and not browser
ALL_MARKS := not browser
else
BROWSER_DEPS := browser-deps
TEST_MARKS := not slow
ALL_MARKS :=
endif

# the suite runs in TEST_WORKERS processes (pytest-xdist), a test file to one of them; 1 runs it in this one
TEST_WORKERS ?= 2
ifeq ($(TEST_WORKERS),1)
TEST_PROCS :=
else
TEST_PROCS := -n $(TEST_WORKERS) --dist loadfile
endif
# a test process runs hundreds of consoles and worlds on many threads: with glibc's default of one
# heap per thread (up to 8 a core) the memory they free stays mapped, ~7 GB a worker by the end
# (malloc_trim gives it back: not a leak). With two heaps a worker peaked at 3.9 GB (7.7 GB without).
test test-all: export MALLOC_ARENA_MAX := 2

.PHONY: run test test-all bench perceive-bench clean-venv browser-deps lock

# the console and what it imports (pyproject.toml's `console` extra) at the versions in constraints.txt
$(RUN_STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install $(PIP_FLAGS) --upgrade pip
	$(BIN)/python -m pip install $(PIP_FLAGS) -c constraints.txt -e ".[console]"
	touch $(RUN_STAMP)

# every extra (pyproject.toml) at the versions in constraints.txt
$(STAMP): pyproject.toml constraints.txt
	@free=$$(df -Pk . | awk 'NR==2 {print int($$4 / 1048576)}'); if [ "$$free" -lt 9 ]; then \
	  echo "make: warning: $$free GB free here; 'make test' installs ~7.2 GB into $(VENV) (torch with its CUDA libraries)" \
	       "and pip needs room for the wheels while it installs" >&2; fi
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install $(PIP_FLAGS) --upgrade pip
	# torch and torchvision must be this pair (both come from local disk here)
	$(BIN)/python -m pip install $(PIP_FLAGS) -c constraints.txt "torch==2.14.1" "torchvision==0.29.1"
	$(BIN)/python -m pip install $(PIP_FLAGS) -c constraints.txt -e ".[all,dev]"
	touch $(STAMP)

# after changing dependencies: install them (make test), then freeze the working .venv
lock: $(STAMP)
	{ echo "# The versions \`make run\` / \`make test\` install (pip -c): frozen from a .venv whose tests pass."; \
	  echo "# After changing dependencies in pyproject.toml: make lock (rewrites this file from .venv)."; \
	  $(BIN)/python -m pip list --format=freeze --exclude-editable | grep -viE '^(pip|setuptools|wheel)=='; \
	} > constraints.txt.tmp && mv constraints.txt.tmp constraints.txt

run: $(RUN_STAMP)
	$(BIN)/shelfpick console --source demo

test: $(STAMP) $(BROWSER_DEPS)
	$(BIN)/python -m pytest -q $(TEST_PROCS) -m "$(TEST_MARKS)"

test-all: $(STAMP) $(BROWSER_DEPS)
	$(BIN)/python -m pytest -q $(TEST_PROCS) -m "$(ALL_MARKS)"

# as .ci/run does: install chromium when missing and we are root; otherwise say what to do
browser-deps:
	@if [ -x $(CHROMIUM) ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	  echo "make: installing Debian's chromium for the browser tests (apt-get install chromium)"; \
	  export DEBIAN_FRONTEND=noninteractive; \
	  apt-get update -qq && apt-get install -y -qq chromium >/dev/null \
	    || { echo "make: apt-get could not install chromium; install it, or run 'make test BROWSER_TESTS=0'" >&2; exit 1; }; \
	else \
	  echo "make: the browser tests need Debian's chromium at $(CHROMIUM): run 'sudo apt-get install -y chromium'" \
	       "and 'make test' again, or 'make test BROWSER_TESTS=0' to run everything else" >&2; \
	  exit 1; \
	fi

clean-venv:
	rm -rf $(VENV)
