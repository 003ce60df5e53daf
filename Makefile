# The README's commands.  Each bootstraps .venv on first use (python3 + pip, nothing else).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
PYTEST := $(BIN)/python -m pytest

.PHONY: run test stress bench bench-tools lint install clean-data screenshots docs

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	# Printrun's printcore (a reference host the hardware tests drive): needs only pyserial;
	# --no-deps keeps its GUI dependencies (wxPython...) out
	$(BIN)/python -m pip install -q --no-deps 'printrun==2.2.0'
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/conforma serve

# four workers on the two cores: tests that share one real resource of the host (LinuxCNC,
# Redis, the browser) stay on one worker per group (tests/conftest.py, SHARED_RESOURCE_GROUPS;
# as root the LinuxCNC modules are two groups, each with a simulator of its own), and a LinuxCNC
# group's worker mostly waits on its simulator's real time, so two more workers keep both cores
# busy (idle 4 % of the run; 0.88x the wall time of three workers, docs/measured.md, "The default
# suite").  Bytecode is written even where the environment sets PYTHONDONTWRITEBYTECODE: else every worker re-compiles the
# sources and pytest re-rewrites the asserts of ~280 plugin modules (schemathesis, hypothesis)
# at each start: 30 CPU s of a worker's collection against 15 with the caches
# (`/usr/bin/time python -m pytest --collect-only -q`), and every server a test starts
# compiles the service again
XDIST := -n 4 --dist loadgroup
test: $(STAMP)
	env -u PYTHONDONTWRITEBYTECODE $(PYTEST) $(XDIST)

# the browser and machine tests, STRESS_RUNS fresh sessions one after another beside stress-ng's
# STRESS_LOAD; prints each run's failures and, last, how many runs failed (tests/helpers/stress.py)
STRESS_RUNS ?= 20
STRESS_LOAD ?= --cpu 2 --cpu-load 60
stress: $(STAMP)
	command -v stress-ng >/dev/null || apt-get install -y --no-install-recommends stress-ng || \
		{ echo "stress: cannot install stress-ng (apt-get, as root)"; exit 1; }
	$(BIN)/python -m tests.helpers.stress --runs $(STRESS_RUNS) --load "$(STRESS_LOAD)" -- \
		$(XDIST) tests/e2e/browser tests/hardware

# the reference slicers the benches run beside ours (Debian packages; Cura's definition files
# come from the `cura` package, extracted without its GUI dependencies)
CURA_RESOURCES ?= $(VENV)/cura/usr/share/cura/resources
export CURA_RESOURCES

bench-tools:
	command -v prusa-slicer >/dev/null && command -v CuraEngine >/dev/null || \
		apt-get install -y --no-install-recommends prusa-slicer cura-engine time || \
		{ echo "bench: cannot install prusa-slicer and cura-engine (apt-get, as root)"; exit 1; }
	test -f $(CURA_RESOURCES)/definitions/fdmprinter.def.json || \
		{ mkdir -p $(VENV)/cura && cd $(VENV)/cura && apt-get download cura && dpkg-deb -x cura_*.deb . ; } || \
		{ echo "bench: cannot fetch Cura's definition files (apt-get download cura)"; exit 1; }

bench: $(STAMP) bench-tools
	$(PYTEST) tests/bench -o addopts="" -s -q -p no:cacheprovider

screenshots: $(STAMP)
	$(PYTEST) tests/e2e/browser
	cp tests/artifacts/screenshots/*.png web/screenshots/

# the manual (docs/*.md) as a site in build/docs/; --strict: any warning fails the build
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict -f docs/config/mkdocs.yml

# the console's JavaScript lint: ESLint pinned by web/package-lock.json, installed into
# web/node_modules (git-ignored) by `npm ci` on first use and again when the lockfile changes
WEB_STAMP := web/node_modules/.installed-stamp

$(WEB_STAMP): web/package-lock.json
	command -v npm >/dev/null || { echo "lint: the console's lint needs node and npm (apt-get install nodejs npm)"; exit 1; }
	cd web && npm ci --no-audit --no-fund
	touch $(WEB_STAMP)

lint: $(STAMP) $(WEB_STAMP)
	$(BIN)/ruff check app hardware tests
	cd web && node_modules/.bin/eslint --max-warnings 0 js  # web/eslint.config.js
	$(BIN)/python -m mypy  # app/ and hardware/ (pyproject [tool.mypy]: strict for the core and the machine backends)

clean-data:
	rm -rf data
