# One-command set-up: every target bootstraps .venv from requirements.lock on a fresh machine.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run serve test lint typecheck check bench lock clean

$(STAMP): requirements.lock pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade "pip>=24"
	$(BIN)/python -m pip install --quiet -r requirements.lock
	$(BIN)/python -m pip install --quiet --no-deps -e .
	touch $(STAMP)

run: $(STAMP)  ## the main job on embedded defaults: plan the reference bay insertion into out/
	mkdir -p out
	$(BIN)/cabinplan plan tests/scenarios/aisle-bay-insert.yaml -o out/aisle-bay-insert.json \
		--csv out/aisle-bay-insert.csv --plot out/aisle-bay-insert.png

serve: $(STAMP)  ## the HTTP service on 127.0.0.1:8000 (embedded defaults; prints the local API key)
	$(BIN)/python -m api

test: $(STAMP)  ## lint, type-check and the whole test suite
	$(BIN)/ruff check planner api tests bench
	$(BIN)/mypy planner api
	$(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check planner api tests bench
	$(BIN)/ruff format --check planner api tests bench

typecheck: $(STAMP)
	$(BIN)/mypy planner api

bench: $(STAMP)
	$(BIN)/python -m bench.kinematics
	$(BIN)/python -m bench.collision
	$(BIN)/python -m bench.planning
	$(BIN)/python -m bench.stiffness
	$(BIN)/python -m bench.timing
	$(BIN)/python -m bench.pprs6
	$(BIN)/python -m bench.startup

lock:  ## re-pin requirements.lock from a fresh resolve of pyproject.toml
	rm -rf /tmp/cabinplan-lock && $(PYTHON) -m venv /tmp/cabinplan-lock
	/tmp/cabinplan-lock/bin/pip install --quiet ".[dev]"
	/tmp/cabinplan-lock/bin/pip freeze --exclude cabinplan > requirements.lock

clean:
	rm -rf $(VENV) build *.egg-info .mypy_cache .ruff_cache .pytest_cache
