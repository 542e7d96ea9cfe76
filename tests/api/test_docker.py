"""The Dockerfile (no engine on the CI machine: its promises are checked by reading it)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _instructions() -> list[tuple[str, str]]:
    text = (ROOT / "Dockerfile").read_text(encoding="utf-8").replace("\\\n", " ")
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            op, _, rest = line.partition(" ")
            out.append((op.upper(), rest.strip()))
    return out


def test_slim_base_lock_file_then_project_without_deps() -> None:
    ins = _instructions()
    assert ins[0] == ("FROM", "python:3.11-slim")
    runs = [rest for op, rest in ins if op == "RUN"]
    lock = next(i for i, r in enumerate(runs) if "-r requirements.lock" in r)
    project = next(i for i, r in enumerate(runs) if "--no-deps ." in r)
    assert lock < project
    assert ("COPY", "requirements.lock ./") in ins


def test_runs_as_a_non_root_user_with_a_healthcheck_on_the_health_route() -> None:
    ins = _instructions()
    users = [rest for op, rest in ins if op == "USER"]
    assert users and users[-1] not in ("root", "0")
    user_at = max(i for i, (op, _) in enumerate(ins) if op == "USER")
    cmd_at = max(i for i, (op, _) in enumerate(ins) if op == "CMD")
    assert user_at < cmd_at
    health = [rest for op, rest in ins if op == "HEALTHCHECK"]
    assert len(health) == 1 and "/api/v1/health" in health[0]
    env = " ".join(rest for op, rest in ins if op == "ENV")
    assert re.search(r"CABINPLAN_HOST=0\.0\.0\.0", env) and "CABINPLAN_DATA_DIR=/data" in env


def test_dockerignore_keeps_the_venv_and_git_out() -> None:
    ignored = (ROOT / ".dockerignore").read_text(encoding="utf-8").split()
    assert {".git", ".venv"} <= set(ignored)


def _pins(name: str) -> tuple[list[str], dict[str, str]]:
    """(include lines, {canonical name: version}) of a lock file; every pin must be exact."""
    includes, pins = [], {}
    for line in (ROOT / name).read_text(encoding="utf-8").splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("-r "):
            includes.append(line[3:].strip())
            continue
        m = re.fullmatch(r"([A-Za-z0-9._-]+)==([A-Za-z0-9.+!-]+)", line)
        assert m, f"{name}: not an exact pin: {line!r}"
        pins[re.sub(r"[-_.]+", "-", m.group(1)).lower()] = m.group(2)
    return includes, pins


def _names(requirements: list[str]) -> set[str]:
    return {re.sub(r"[-_.]+", "-", re.split(r"[\[<>=!~ ;]", r, maxsplit=1)[0]).lower() for r in requirements}


def test_runtime_and_development_pins_are_split_and_the_image_installs_only_the_runtime_set() -> None:
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    run_includes, runtime = _pins("requirements.lock")
    dev_includes, dev = _pins("requirements-dev.lock")
    assert run_includes == [] and dev_includes == ["requirements.lock"]
    assert not set(runtime) & set(dev)  # each package pinned once
    assert _names(project["dependencies"]) <= set(runtime)
    dev_tools = _names(project["optional-dependencies"]["dev"]) - set(runtime)
    assert dev_tools <= set(dev) and {"pytest", "mypy", "ruff", "hypothesis", "schemathesis"} <= dev_tools
    assert not {"pytest", "mypy", "ruff", "hypothesis", "schemathesis"} & set(runtime)
    docker = " ".join(rest for op, rest in _instructions() if op in ("COPY", "RUN", "ADD"))
    assert (
        "requirements-dev.lock" not in docker and "[dev]" not in docker and "-r requirements.lock" in docker
    )
    make = (ROOT / "Makefile").read_text(encoding="utf-8")
    assert re.search(r"^test: \$\(DEV_STAMP\)", make, re.M) and "-r requirements-dev.lock" in make
    assert re.search(r"^serve: \$\(STAMP\)", make, re.M)
