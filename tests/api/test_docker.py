"""The Dockerfile: its promises checked by reading it, and what its build stage builds checked in process.

No container engine runs on the CI machine: :func:`test_the_image_builds_and_plans` builds and runs the
image where one is (docker or podman) and skips, saying so, elsewhere. The rest needs none: the stages
(a build stage with a C compiler that builds the kernels portably, a slim final stage without one that
carries the cache folder) and that a portable build made the way the build stage makes it loads in a
process that targets its own CPU, with the numbers of the JIT.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

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


def _stages() -> list[list[tuple[str, str]]]:
    """The instructions of each stage (from its FROM to the next)."""
    stages: list[list[tuple[str, str]]] = []
    for op, rest in _instructions():
        if op == "FROM":
            stages.append([])
        stages[-1].append((op, rest))
    return stages


def _env(stage: list[tuple[str, str]]) -> dict[str, str]:
    return dict(re.findall(r"([A-Z_]+)=(\S+)", " ".join(rest for op, rest in stage if op == "ENV")))


def test_slim_base_lock_file_then_project_without_deps() -> None:
    build, final = _stages()
    assert build[0] == ("FROM", "python:3.11-slim AS build") and final[0] == ("FROM", "python:3.11-slim")
    ins = build
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


def test_a_build_stage_with_a_compiler_builds_the_kernels_portably_and_the_slim_stage_carries_them() -> None:
    build, final = _stages()
    build_runs = " ".join(rest for op, rest in build if op == "RUN")
    assert re.search(r"apt-get install [^&]*\bgcc\b", build_runs)
    for command in (
        "python -m planner.collision.kernels.build",
        "python -m planner.timing.acc_reference",
        "import api.warmup",  # plans once: the native CasADi builds, numba's cache, the aisle grid
        "from api.prebuilt import check; check()",  # the stage fails when a build is missing
    ):
        assert command in build_runs, command
    env = _env(build)
    assert env["CABINPLAN_AOT_CPU"] == "generic" and env["NUMBA_CPU_NAME"] == "generic"
    cache = env["CABINPLAN_CACHE_DIR"]
    assert env["NUMBA_CACHE_DIR"].startswith(cache + "/")
    # The final stage: no compiler, the environment and the cache folder copied, the same folder named.
    final_text = " ".join(rest for _, rest in final)
    assert "apt-get" not in final_text and "gcc" not in final_text
    copies = [rest for op, rest in final if op == "COPY"]
    assert any(c.startswith("--from=build") and c.split()[-2:] == [cache, cache] for c in copies), copies
    assert any(c.startswith("--from=build") and c.split()[-1] == "/opt/venv" for c in copies), copies
    final_env = _env(final)
    assert final_env["CABINPLAN_CACHE_DIR"] == cache and final_env["NUMBA_CPU_NAME"] == "generic"
    assert final_env["NUMBA_CACHE_DIR"] == env["NUMBA_CACHE_DIR"]
    users = [rest for op, rest in final if op == "USER"]
    owner = next(c for c in copies if c.split()[-1] == cache)
    assert f"--chown={users[-1]}:" in owner  # new cabins' grids are written into it at run time


def test_a_portable_build_loads_on_a_machine_that_targets_its_own_cpu(tmp_path, monkeypatch) -> None:
    """Built as the image's build stage builds it (generic CPU), loaded as the slim image loads it.

    The loading process targets its own CPU (``host``), has no build of its own, and must neither build
    one nor fall back to the JIT: it takes the portable build, whose key does not change with the CPU,
    and computes what the JIT computes. On x86-64 the portable code uses no AVX register.
    """
    from planner.core import aot
    from planner.timing import acc_reference as reference

    cache = tmp_path / "cache"
    env = {
        **os.environ,
        "CABINPLAN_CACHE_DIR": str(cache),
        "CABINPLAN_AOT_CPU": "generic",
        "PYTHONPATH": str(ROOT),
    }
    subprocess.run([sys.executable, "-m", "planner.timing.acc_reference"], env=env, check=True, cwd=tmp_path)
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(cache))
    monkeypatch.delenv("CABINPLAN_AOT_CPU", raising=False)
    monkeypatch.delenv("CABINPLAN_KERNELS", raising=False)
    portable = aot.path(reference.EXTENSION, "generic")
    assert portable is not None and portable.is_file()
    assert not aot.path(reference.EXTENSION).is_file()  # type: ignore[union-attr]  # no host build here

    # Another machine: another CPU identity, the same portable key; the host key changes with it.
    host_key, generic_key = aot.key(reference.EXTENSION, "host"), aot.key(reference.EXTENSION, "generic")
    monkeypatch.setattr(aot, "_cpu_identity", lambda: "vendor_id: OtherCPU\nflags: sse2")
    assert aot.key(reference.EXTENSION, "generic") == generic_key
    assert aot.key(reference.EXTENSION, "host") != host_key

    def no_build(ext: aot.Extension) -> None:
        raise AssertionError(f"{ext.name}: built although a portable build is in the cache")

    monkeypatch.setattr(aot, "_build_in_subprocess", no_build)
    module = aot.kernels(reference.EXTENSION)
    assert module.__file__ == str(portable)
    rng = np.random.default_rng(3)
    n = 40
    cx, cy = rng.uniform(-1, 1, (n + 1, 4)), rng.uniform(0.5, 1.5, (n + 1, 4))
    b = rng.uniform(0.5, 2.0, (n + 1, 4))
    args = (np.full(n, 0.05), cx, cy, b, rng.uniform(0.5, 2.0, n + 1))
    built = reference.acceleration_limited(*args, implementation=module)
    jit = reference.acceleration_limited(*args, implementation=aot.jit_kernels(reference.EXTENSION))
    np.testing.assert_array_equal(built, jit)
    objdump = shutil.which("objdump")
    if objdump and os.uname().machine == "x86_64":
        code = subprocess.run(
            [objdump, "-d", str(portable)], capture_output=True, text=True, check=True
        ).stdout
        assert not re.search(r"%[yz]mm\d", code), "the portable build uses AVX registers"


def _engine() -> str | None:
    for name in ("docker", "podman"):
        path = shutil.which(name)
        if path and subprocess.run([path, "info"], capture_output=True, timeout=30).returncode == 0:
            return path
    return None


@pytest.mark.slow
def test_the_image_builds_and_plans(tmp_path) -> None:
    """Where a container engine runs: build the image, start it, plan the reference bay insertion."""
    engine = _engine()
    if engine is None:
        pytest.skip("no container engine (docker or podman) runs here: the image is checked by reading it")
    tag = "cabinplan-test:latest"
    subprocess.run([engine, "build", "-t", tag, str(ROOT)], check=True, timeout=3600)
    script = (
        "from api.prebuilt import missing; assert not missing(), missing(); "
        "import api.warmup; print('ok')"  # plans the warm-up scenario in the container
    )
    out = subprocess.run([engine, "run", "--rm", tag, "python", "-c", script], capture_output=True, text=True)
    assert "no ahead-of-time build" not in out.stderr and "unavailable" not in out.stderr, out.stderr
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr


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
