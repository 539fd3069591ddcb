# Two entry points do all the set-up on a fresh machine: `make demo` and `make test`.
SHELL := /bin/bash
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO := runs/demo
# Versions known to pass; floors stay in pyproject.toml. `make test-latest` tries the newest on purpose.
CONSTRAINTS := constraints.txt
EXTRAS := test,lint,orbslam3,dask
LATEST := .venv-latest
LINTED := slzcli tests benchmarks scripts

.PHONY: demo test test-fast lint test-latest constraints sysdeps venv bench clean docs

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

$(STAMP): pyproject.toml $(CONSTRAINTS) | sysdeps
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q -c $(CONSTRAINTS) --upgrade pip
	$(BIN)/python -m pip install -q -c $(CONSTRAINTS) -e '.[$(EXTRAS)]'
	touch $(STAMP)

venv: $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff check $(LINTED)
	$(BIN)/mypy

# Every core, a test file per worker (module fixtures stay in one process).
PYTEST_PAR := -n auto --dist loadfile

test: lint
	$(BIN)/python -m pytest $(PYTEST_PAR)

# The edit-run loop: everything but the tests marked slow (whole commands on rendered recordings,
# simulated descents, property tests: tests/conftest.py SLOW_FILES); `make test` still runs all.
test-fast: $(STAMP)
	$(BIN)/python -m pytest $(PYTEST_PAR) -m "not slow"

# The newest releases that meet pyproject's floors, in a scratch venv, through lint and the whole suite.
# When it passes, `make constraints` records those versions as the new known-good set.
test-latest: sysdeps
	rm -rf $(LATEST)
	$(PY) -m venv $(LATEST)
	$(LATEST)/bin/python -m pip install -q --upgrade pip
	$(LATEST)/bin/python -m pip install -q --upgrade --upgrade-strategy eager -e '.[$(EXTRAS)]'
	$(LATEST)/bin/python -m pip freeze --all --exclude-editable > $(LATEST)/versions.txt
	$(LATEST)/bin/ruff check $(LINTED)
	$(LATEST)/bin/mypy
	$(LATEST)/bin/python -m pytest $(PYTEST_PAR)
	touch $(LATEST)/.passed
	@echo "newest releases pass; 'make constraints' records them in $(CONSTRAINTS)"

constraints:
	@test -f $(LATEST)/.passed || { echo "run 'make test-latest' first: only a set that passed is recorded"; exit 1; }
	{ sed -n '/^#/p' $(CONSTRAINTS); cat $(LATEST)/versions.txt; } > $(CONSTRAINTS).new
	mv $(CONSTRAINTS).new $(CONSTRAINTS)
	@git --no-pager diff --stat -- $(CONSTRAINTS) 2>/dev/null || true

# Render a ground-truthed flight, read it, detect the landing site, simulate the IBVS descent.
# The flight descends from 7 m (the paper's scenario 3) to 2 m under the default D435-like stereo depth (848x480
# infrared pair): the high frames cannot vouch for a site (their noise hides steps the UAV cannot take), the low
# ones can. 30 frames at 3 Hz: 50 of 50 ORB-SLAM3 runs of `slz detect` committed a truly safe site (clearance
# 1.9 m). From 8 m to 3 m 6 of 110 runs ended without one (the descent's sparse map-point clusters refused by the
# raised-surface weighing or the acceptance test, as ORB-SLAM3's threads drew them): an honest answer, but a demo
# should not hang on one draw. At 424x240 (faster to render) the noise doubles and only the lowest frame vouched.
# Progress shows on stderr throughout.
demo: $(STAMP)
	@mkdir -p $(DEMO)
	$(BIN)/slz synth parking_lot -o $(DEMO)/parking_lot.mcap --frames 30 --rate 3 --path descent --scenario 3 --force
	$(BIN)/slz info $(DEMO)/parking_lot.mcap
	$(BIN)/slz detect $(DEMO)/parking_lot.mcap -o $(DEMO)/run --force
	$(BIN)/slz land simulate $(DEMO)/run --offset 2,-1.5,8
	@echo
	@echo "Results are in $(DEMO)/; open the report first:"
	@echo "  run/report.html             the run at a glance: site, trajectory, every detection frame"
	@echo "  run/landing.json            the chosen site (or why there is none), its height above ground and start"
	@echo "  run/frames/*/overlay.png    safe / unsafe / undecided, SLAM points and the landing square, per keyframe"
	@echo "  run/run.json                timings, tracking, accuracy against ground truth"
	@echo "  run/ibvs/                   the simulated descent: metrics.json, trajectory.csv, plots"
	@echo "  parking_lot.mcap.preview.png  contact sheet: colour, depth, object ids, true safe area"
	@echo "More scenes: $(BIN)/slz synth --list"

# The documentation site (docs/ -> site/): mkdocs with the material theme, strict (a warning fails the build).
DOCS_STAMP := $(VENV)/.docs-installed
$(DOCS_STAMP): $(STAMP)
	$(BIN)/python -m pip install -q -c $(CONSTRAINTS) -e '.[docs]'
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet
	@echo "site/index.html"

bench: $(STAMP)
	for b in read synth terrain scoring masks stages slam ibvs; do $(BIN)/python benchmarks/$$b.py || exit 1; done

clean:
	rm -rf $(VENV) $(LATEST) runs site .pytest_cache .mypy_cache .ruff_cache
