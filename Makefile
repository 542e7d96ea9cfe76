# One-command set-up: every target bootstraps .venv on a fresh machine: `run` and `serve` from the runtime
# pins (requirements.lock), `test`, `lint`, `typecheck` and `bench` from the development pins as well
# (requirements-dev.lock = runtime pins + test, lint and type-check tools).
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEV_STAMP := $(VENV)/.installed-dev

.PHONY: run serve test lint typecheck check bench lock clean chromium

# After installing: the compiled kernels built ahead of time into the cache folder (about 15 s; without a
# C compiler plans use numba's JIT instead, README "Start-up").
$(STAMP): requirements.lock pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade "pip>=24"
	$(BIN)/python -m pip install --quiet -r requirements.lock
	$(BIN)/python -m pip install --quiet --no-deps -e .
	$(BIN)/python -m planner.collision.kernels.build && $(BIN)/python -m planner.timing.acc_reference \
		|| echo "kernels: no ahead-of-time build (see above); plans will use numba's JIT"
	touch $(STAMP)

$(DEV_STAMP): $(STAMP) requirements-dev.lock
	$(BIN)/python -m pip install --quiet -r requirements-dev.lock
	touch $(DEV_STAMP)

run: $(STAMP)  ## the main job on embedded defaults: plan the reference bay insertion into out/
	mkdir -p out
	$(BIN)/cabinplan plan tests/scenarios/aisle-bay-insert.yaml -o out/aisle-bay-insert.json \
		--csv out/aisle-bay-insert.csv --plot out/aisle-bay-insert.png

serve: $(STAMP)  ## the HTTP service on 127.0.0.1:8000 (embedded defaults; prints the local API key)
	$(BIN)/python -m api

# The suite on two pytest-xdist workers: a module's tests (a folder's, for folders that share session
# fixtures) stay on one worker (tests/conftest.py gives every test its xdist group).
test: $(DEV_STAMP) chromium  ## lint, type-check and the whole test suite (installs Debian's Chromium first)
	$(BIN)/ruff check planner api tests bench
	$(BIN)/mypy planner api
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup

chromium:  ## Debian's Chromium for the viewer's browser tests (they skip without it); never a downloaded browser
	@command -v chromium >/dev/null 2>&1 || { apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; } || \
		echo "chromium: not installed (needs root and Debian's packages): the browser tests will skip"
	@chromium --version 2>/dev/null || true

lint: $(DEV_STAMP)
	$(BIN)/ruff check planner api tests bench
	$(BIN)/ruff format --check planner api tests bench

typecheck: $(DEV_STAMP)
	$(BIN)/mypy planner api

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
	rm -rf $(VENV) build *.egg-info .mypy_cache .ruff_cache .pytest_cache
