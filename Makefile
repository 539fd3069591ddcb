# Two entry points do all the set-up on a fresh machine: `make demo` and `make test`.
SHELL := /bin/bash
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO := runs/demo

.PHONY: demo test sysdeps venv bench clean

# open3d's wheel links against libusb-1.0 and libgomp; install them when absent.
sysdeps:
	@missing=""; \
	for lib in libusb-1.0.so.0 libgomp.so.1; do \
	  ldconfig -p 2>/dev/null | grep -q "$$lib" || missing="$$missing $$lib"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "installing system libraries for:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0 libgomp1 >/dev/null; \
	fi

$(STAMP): pyproject.toml | sysdeps
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest

demo: $(STAMP)
	$(BIN)/python scripts/demo.py $(DEMO)

bench: $(STAMP)
	$(BIN)/python benchmarks/read.py

clean:
	rm -rf $(VENV) runs .pytest_cache
