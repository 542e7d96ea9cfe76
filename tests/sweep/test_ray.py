"""Sweeps on a local Ray (2 CPUs, bound to loopback): the same rows as embedded, hard kills, lost workers."""

from __future__ import annotations

import ipaddress
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from planner.sweep.expand import expand_sweep
from planner.sweep.results import MACHINE_COLUMNS, read_parquet
from planner.sweep.run import RayExecutor, init_local_ray, run_sweep, warm_task
from planner.sweep.spec import sweep_from_dict
from tests.sweep.conftest import bay_sweep, invoke, write_spec
from tests.sweep.test_run import STUCK_LIMIT_S, check_stuck_rows, stuck_sweep

ray = pytest.importorskip(
    "ray", reason="ray is not installed (the [ray] extra: pip install 'cabinplan[ray]')"
)


@pytest.fixture(scope="module")
def local_ray() -> Iterator[Any]:
    init_local_ray(2)
    try:
        yield ray
    finally:
        ray.shutdown()


def _descendants(root: int) -> set[int]:
    """Process ids of ``root`` and every process below it (Ray's GCS, raylet, agents and workers)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            children.setdefault(ppid, []).append(int(entry.name))
    out, todo = set(), [root]
    while todo:
        pid = todo.pop()
        out.add(pid)
        todo.extend(children.get(pid, []))
    return out


def _socket_inodes(pids: set[int]) -> dict[str, int]:
    out = {}
    for pid in pids:
        try:
            for fd in Path(f"/proc/{pid}/fd").iterdir():
                target = os.readlink(fd)
                if target.startswith("socket:["):
                    out[target[8:-1]] = pid
        except OSError:  # the process ended, or is not ours to read
            continue
    return out


def _address(hex_ip: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address:
    raw = bytes.fromhex(hex_ip)
    if len(raw) == 4:
        return ipaddress.IPv4Address(raw[::-1])
    words = b"".join(raw[k : k + 4][::-1] for k in range(0, 16, 4))  # four host-order 32-bit words
    return ipaddress.IPv6Address(words)


def _listening(inodes: dict[str, int]) -> list[tuple[str, int, str]]:
    """(protocol, pid, local address) of every listening TCP and bound UDP socket of those inodes."""
    found = []
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        path = Path(f"/proc/net/{proto}")
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            local, state, inode = fields[1], fields[3], fields[9]
            if inode in inodes and (proto.startswith("udp") or state == "0A"):  # 0A: TCP LISTEN
                found.append((proto, inodes[inode], local))
    return found


def test_a_local_ray_listens_on_loopback_only(local_ray):
    @ray.remote
    def pid() -> int:
        return os.getpid()

    workers = set(ray.get([pid.remote() for _ in range(2)]))
    ours = _descendants(os.getpid())
    assert workers <= ours  # the workers are below this process (Ray was started here)
    sockets = _listening(_socket_inodes(ours))
    assert len({p for _, p, _ in sockets}) >= 4  # GCS, raylet, the workers, this driver at least
    for proto, owner, local in sockets:
        ip = _address(local.split(":")[0])
        if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
            ip = ip.ipv4_mapped
        assert ip.is_loopback, (proto, owner, str(ip), Path(f"/proc/{owner}/cmdline").read_bytes()[:80])


def _plan_workers() -> list[int]:
    """Process ids of Ray workers executing a sweep plan right now (their title is ray::_ray_plan)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmdline = (entry / "cmdline").read_bytes()
            except OSError:
                continue
            if cmdline.startswith(b"ray::_ray_plan"):
                pids.append(int(entry.name))
    return pids


def test_ray_gives_the_rows_the_embedded_run_gives(local_ray, embedded_run, tmp_path: Path):
    _, embedded = embedded_run
    spec = write_spec(tmp_path, bay_sweep())
    result = invoke("sweep", spec, "-o", tmp_path / "out", "--ray")
    assert result.exit_code == 0, result.stderr
    rows = read_parquet(tmp_path / "out" / "results.parquet")

    def same(row: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in row.items() if k not in MACHINE_COLUMNS}

    assert [same(r) for r in rows] == [same(r) for r in embedded]
    assert {r["status"] for r in rows} == {"succeeded", "failed"}


def test_ray_kills_a_plan_at_its_limit_and_a_killed_worker_loses_no_row(local_ray, tmp_path: Path):
    sweep = sweep_from_dict(stuck_sweep("ray-stuck", STUCK_LIMIT_S))
    plans = expand_sweep(sweep)
    # Warm workers on the quick feasible plan: a worker started after the kill warms up before the
    # retried plan starts (the stuck plan as warm-up task would search for 5 s first).
    executor = RayExecutor(max_in_flight=2, warm_task=warm_task(plans[2:]))
    outcome: dict[str, Any] = {}

    def run() -> None:
        outcome["counts"] = run_sweep(plans, tmp_path, executor, sweep.limits, poll_s=0.05)

    thread = threading.Thread(target=run)
    thread.start()
    killed = None
    deadline = time.monotonic() + 60
    while killed is None and time.monotonic() < deadline and thread.is_alive():
        pid = executor.started.get(plans[0].sha256)  # the long plan, once its worker has started it
        if pid is not None:
            assert pid in _plan_workers()  # a real Ray worker process, executing a sweep plan
            os.kill(pid, signal.SIGKILL)  # the worker dies mid-task
            killed = pid
        time.sleep(0.02)
    thread.join(timeout=120)
    executor.close()
    assert killed is not None, "the long plan was never seen running"
    assert not thread.is_alive()
    counts = outcome["counts"]
    assert counts.retried == 1
    rows = read_parquet(tmp_path / "results.parquet")
    assert len({r["scenario_sha256"] for r in rows}) == 3
    assert [r["attempts"] for r in sorted(rows, key=lambda r: r["plan"])] == [2, 1, 1]
    check_stuck_rows(rows, STUCK_LIMIT_S)
