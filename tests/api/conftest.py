"""Fixtures of the HTTP service tests: the real app on a real SQLite file in tmp_path."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml
from fastapi.testclient import TestClient

from api.app import create_app
from api.auth import create_key
from api.settings import Settings

ADMIN_KEY = "cpk_test-admin-key-0123456789"
SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
ROOT = Path(__file__).resolve().parents[2]


def scenario(name: str, **options: Any) -> dict[str, Any]:
    """A scenario of the suite as a dict (the HTTP body), with options overridden."""
    data: dict[str, Any] = yaml.safe_load((SCENARIOS / f"{name}.yaml").read_text(encoding="utf-8"))
    data.setdefault("options", {}).update(options)
    return data


def stuck(seed: int, time_limit_s: float = 20.0) -> dict[str, Any]:
    """The hatch pass with a payload too bulky for the hatch: the search runs to its time limit.

    Valid start and goal, so the job runs (rather than being refused at once) for as long as the test
    needs a busy worker, however fast planning gets (measured: no path within 8 s on seeds 11-13).
    """
    data = scenario("hatch-pass", seed=seed, time_limit_s=time_limit_s)
    data["payload"]["box"] = [0.5, 0.5, 0.45]
    data["payload"]["grasp"]["position"] = [0.0, 0.0, 0.3]
    return data


def free_transfer(d1_goal: float = 1.6, **options: Any) -> dict[str, Any]:
    """A short free-space rail move without payload: plans in well under a second."""
    home = {"d1": 1.0, "x1": -0.46, "x2": 0.46, "x3": -0.09, "theta3": 1.2, "theta4": -0.8, "d5": -0.25}
    return {
        "name": "free-transfer",
        "robot": "cabin8",
        "start": {"drives": {**home, "theta6": 0.0}},
        "goal": {"drives": {**home, "d1": d1_goal, "theta6": 0.0}},
        "options": {"seed": 1, "time_limit_s": 20, **options},
    }


def make_settings(tmp_path: Path, **overrides: Any) -> Settings:
    values: dict[str, Any] = {
        "data_dir": tmp_path / "data",
        "admin_key": ADMIN_KEY,
        "workers": 2,
        "job_grace_s": 20.0,
        "tenant_max_active_jobs": 4,
        "rate_limit": "100000 per 1 second",  # the rate-limit test sets its own
        **overrides,
    }
    return Settings(**values)


class Service:
    """A running app (TestClient with lifespan) and one key per tenant."""

    def __init__(self, client: TestClient, keys: dict[str, str]) -> None:
        self.client = client
        self.keys = keys

    def h(self, tenant: str = "alpha") -> dict[str, str]:
        return {"X-API-Key": self.keys[tenant]}


def start_service(settings: Settings) -> Iterator[Service]:
    app = create_app(settings)
    with TestClient(app, raise_server_exceptions=False) as client:
        ctx = app.state.ctx
        keys = {t: create_key(ctx, t, f"{t} test key")[1] for t in ("alpha", "beta")}
        keys["admin"] = ADMIN_KEY
        yield Service(client, keys)


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    yield from start_service(make_settings(tmp_path_factory.mktemp("svc")))


class IdleRunner:
    """A job runner that never runs anything: jobs stay queued (quota, cancel-queued, fuzzing tests)."""

    def __init__(self) -> None:
        self.instance_id = "idle"
        self.woken = 0
        self.cancelled: list[str] = []
        self.started = False

    def start(self) -> None:
        self.started = True

    def stop(self) -> None:
        self.started = False

    def wake(self) -> None:
        self.woken += 1

    def cancel(self, job_id: str) -> None:
        self.cancelled.append(job_id)

    def on_job_end(self, listener: Callable[[str], None]) -> None:
        """No job ever ends here."""

    def alive(self) -> bool:
        return self.started

    def busy(self) -> int:
        return 0

    def warming(self) -> str | None:
        return None


def start_idle_service(settings: Settings) -> Iterator[Service]:
    app = create_app(settings, runner=IdleRunner())
    with TestClient(app, raise_server_exceptions=False) as client:
        ctx = app.state.ctx
        keys = {t: create_key(ctx, t, f"{t} test key")[1] for t in ("alpha", "beta")}
        keys["admin"] = ADMIN_KEY
        yield Service(client, keys)


def box_stl(extents: tuple[float, float, float] = (2.0, 2.0, 6.0)) -> bytes:
    """A closed box as binary STL bytes (metres)."""
    import trimesh

    data: bytes = trimesh.creation.box(extents=extents).export(file_type="stl")
    return data


def wait_for(
    client: TestClient, headers: dict[str, str], job_id: str, timeout_s: float = 60.0
) -> dict[str, Any]:
    """Poll a job until it is finished; returns its document."""
    import time

    deadline = time.monotonic() + timeout_s
    while True:
        doc: dict[str, Any] = client.get(f"/api/v1/plans/{job_id}", headers=headers).json()
        if doc["status"] not in ("queued", "running") or time.monotonic() > deadline:
            return doc
        time.sleep(0.1)


# ------------------------------------------------------------ a live server (its own process)
def free_port() -> int:
    """A free TCP port on the loopback interface."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server:
    """``python -m api`` in its own session (process group), on a free loopback port."""

    def __init__(self, data_dir: Path, **env: str) -> None:
        self.data_dir = data_dir
        self.env = env
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen[bytes] | None = None
        self.log = data_dir / "server.log"

    def start(self, wait: str = "ready", timeout_s: float = 300.0) -> None:
        """Start the server; return once ``/api/v1/<wait>`` answers 200 (``ready`` or ``health``).

        ``timeout_s``: how long to wait (``/ready`` waits for the forkserver's warm-up).
        """
        env = {
            **os.environ,
            "CABINPLAN_DATA_DIR": str(self.data_dir),
            "CABINPLAN_PORT": str(self.port),
            "CABINPLAN_ADMIN_KEY": ADMIN_KEY,
            "CABINPLAN_WORKERS": "1",
            **self.env,
        }
        self.data_dir.mkdir(parents=True, exist_ok=True)
        with self.log.open("ab") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "api"],
                cwd=ROOT,
                env=env,
                stdout=log,
                stderr=log,
                start_new_session=True,
            )
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, self.log.read_text()
            try:
                if httpx.get(f"{self.url}/api/v1/{wait}", timeout=1.0).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        raise AssertionError(f"server did not start: {self.log.read_text()}")

    def kill(self) -> None:
        """SIGKILL the server and everything it started (its process group): a crash, no shutdown."""
        assert self.proc is not None
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(timeout=10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.kill()

    def ready(self) -> dict[str, Any]:
        doc: dict[str, Any] = httpx.get(f"{self.url}/api/v1/ready", timeout=10).json()
        return doc
