# Shortcuts for the README's two commands (which need no make):
#   make demo   = scripts/demo.sh: set up what is missing, build, run the demo
#   make test   = scripts/test.sh: set up, build once in release, run every test
.PHONY: deps build demo test test-rust test-python install bench clean-shm

CARGO ?= cargo
VENV ?= $(CURDIR)/.venv
export STAR_VENV := $(VENV)

deps:
	scripts/setup.sh

build: deps
	$(CARGO) build --release

demo:
	scripts/demo.sh

test-rust: deps
	$(CARGO) test --release

test-python: build
	@if ls hil_tests/test_*.py >/dev/null 2>&1; then \
		$(VENV)/bin/python -m pytest -q hil_tests; \
	else echo "hil_tests: no pytest tests yet"; fi

test:
	scripts/test.sh

bench: deps
	$(CARGO) bench

install: build
	scripts/install.sh
