# One-command set-up: every target bootstraps .venv on a fresh machine: `run` and `serve` from the runtime
# pins (requirements.lock), `test`, `lint`, `typecheck` and `bench` from the development pins as well
# (requirements-dev.lock = runtime pins + test, lint and type-check tools).
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEV_STAMP := $(VENV)/.installed-dev

.PHONY: run serve test lint typecheck check bench lock clean chromium

# The pins are installed by uv (pinned here; a wheel from PyPI, into the venv first): the same packages as
# pip installs from the same lock files, in seconds instead of about a minute. The project's own modules
# are compiled to bytecode too (uv compiles only what it installs into the venv, not an editable source
# tree): where PYTHONDONTWRITEBYTECODE is set (CI, many shells and images) Python never writes them, and
# every `cabinplan plan` compiled its ~190 modules again (0.35 s of a call); `run`, `serve` and `test`
# compile what changed since (a tenth of a second when nothing did). Then the compiled kernels,
# built ahead of time into the cache folder (about 65 s on a fresh machine; a build of the same key already
# in the cache -- same kernel sources, compiler, numpy, Python and CPU -- is reused; without a C compiler
# plans use numba's JIT instead, README "Start-up").
UV_VERSION := 0.13.9
UV := $(BIN)/python -m uv pip install --quiet --compile-bytecode --python $(BIN)/python

$(STAMP): requirements.lock pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet "uv==$(UV_VERSION)"
	$(UV) -r requirements.lock
	$(UV) --no-deps -e .
	$(BIN)/python -m compileall -q planner api
	$(BIN)/python -m planner.collision.kernels.build --reuse && $(BIN)/python -m planner.timing.acc_reference --reuse \
		|| echo "kernels: no ahead-of-time build (see above); plans will use numba's JIT"
	touch $(STAMP)

$(DEV_STAMP): $(STAMP) requirements-dev.lock
	$(UV) -r requirements-dev.lock
	touch $(DEV_STAMP)

run: $(STAMP)  ## the main job on embedded defaults: plan the reference bay insertion into out/
	$(BIN)/python -m compileall -q planner api
	mkdir -p out
	$(BIN)/cabinplan plan tests/scenarios/aisle-bay-insert.yaml -o out/aisle-bay-insert.json \
		--csv out/aisle-bay-insert.csv --plot out/aisle-bay-insert.png

serve: $(STAMP)  ## the HTTP service on 127.0.0.1:8000 (embedded defaults; prints the local API key)
	$(BIN)/python -m compileall -q planner api
	$(BIN)/python -m api

# The suite on two pytest-xdist workers: a module's tests (a folder's, for folders that share session
# fixtures) stay on one worker (tests/conftest.py gives every test its xdist group).
# mypy runs beside the tests (the workers wait on servers, browsers and subprocesses a third of the time);
# its output is printed after theirs, and either failing fails the target.
test: $(DEV_STAMP) chromium  ## lint, type-check and the whole test suite (installs Debian's Chromium first)
	$(BIN)/python -m compileall -q planner api
	$(BIN)/ruff check planner api tests bench
	$(BIN)/mypy planner api bench > .mypy.out 2>&1 & mypy=$$!; \
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup; tests=$$?; \
	wait $$mypy; types=$$?; echo "mypy planner api bench:"; cat .mypy.out; rm -f .mypy.out; \
	test $$tests -eq 0 && test $$types -eq 0

chromium:  ## Debian's Chromium for the viewer's browser tests (they skip without it); never a downloaded browser
	@command -v chromium >/dev/null 2>&1 || { apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; } || \
		echo "chromium: not installed (needs root and Debian's packages): the browser tests will skip"
	@chromium --version 2>/dev/null || true

lint: $(DEV_STAMP)
	$(BIN)/ruff check planner api tests bench
	$(BIN)/ruff format --check planner api tests bench

typecheck: $(DEV_STAMP)
	$(BIN)/mypy planner api bench

bench: $(DEV_STAMP)
	$(BIN)/python -m bench.kinematics
	$(BIN)/python -m bench.collision
	$(BIN)/python -m bench.planning
	$(BIN)/python -m bench.stiffness
	$(BIN)/python -m bench.timing
	$(BIN)/python -m bench.pprs6
	$(BIN)/python -m bench.startup
	$(BIN)/python -m bench.load
	$(BIN)/python -m bench.sweep
	mkdir -p out
	$(BIN)/python -m bench.generalization --count 100 --seed 0 --out out/generalization.json
	$(BIN)/python -m bench.generalization --families new --count 10 --seed 0 --no-suite \
		--out out/generalization-families.json

lock:  ## re-pin requirements.lock (runtime) and requirements-dev.lock (development) from pyproject.toml
	rm -rf /tmp/cabinplan-lock && $(PYTHON) -m venv /tmp/cabinplan-lock
	/tmp/cabinplan-lock/bin/pip install --quiet .
	/tmp/cabinplan-lock/bin/pip freeze --exclude cabinplan > /tmp/cabinplan-lock/runtime.txt
	/tmp/cabinplan-lock/bin/pip install --quiet ".[dev]"
	/tmp/cabinplan-lock/bin/pip freeze --exclude cabinplan > /tmp/cabinplan-lock/all.txt
	{ echo "# Runtime pins (exact); the Docker image installs only these. Development: requirements-dev.lock."; \
	  cat /tmp/cabinplan-lock/runtime.txt; } > requirements.lock
	{ echo "# Development pins (exact): the runtime set plus tests, lint and type-check tools."; \
	  echo "-r requirements.lock"; grep -vxFf /tmp/cabinplan-lock/runtime.txt /tmp/cabinplan-lock/all.txt; } \
	  > requirements-dev.lock

clean:
	rm -rf $(VENV) build *.egg-info .mypy_cache .ruff_cache .pytest_cache .mypy.out
