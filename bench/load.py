"""Load check of the HTTP service: concurrent clients submitting the reference scenarios.

Starts the real server (``python -m api``, temp data dir, SQLite), then ``--clients`` threads (each with its
HTTP session made before the load starts, as a plant's client holds one) each submit
``--rounds`` reference scenarios one after another (round robin over the suite's succeeding scenarios), each
waited for to its end with long polls (``GET /plans/{id}?wait_s=30``: answered when the plan ends), while a
prober calls ``/health`` every 50 ms. Prints throughput, p50/p95/max latency of ``/health`` and of ``GET
/plans/{id}`` under load, ``POST /plans`` latency under load next to the same submissions made one at a time
on the idle server first (each cancelled at once), and how many results pass the validation gate: the gate
report stored with each plan, and an independent re-run of the gate through ``POST /plans:validate``.

In the same run, before the server starts and again after it stopped, ``--workers`` in-process planners (one
process each, warmed up on every scenario first, at the niceness of the service's job processes) plan the
same list of plans the clients submit: plans a minute in process (both runs, and their mean: a VM's speed
drifts by 10-30% over a minute), next to the service's, and their ratio (the service's overhead:
handing a job to a worker, its documents, the database, the HTTP requests and the clients themselves, which
share the machine), and the median job overhead (a job's run time minus its own ``planning_time_s``). The
load average is printed at the start and the end (a shared machine), and the resident memory of the
service's processes after the run.

    python -m bench.load [--clients 20] [--workers 2] [--rounds 3]
"""

from __future__ import annotations

import argparse
import gc
import multiprocessing
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import orjson
import yaml

from api.settings import Settings
from planner.core.procpool import SINGLE_THREAD_ENV

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "tests" / "scenarios"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def reference_scenarios() -> list[dict[str, Any]]:
    expected = yaml.safe_load((SCENARIOS / "expected.yaml").read_text())
    names = [n for n, e in expected.items() if e["status"] == "succeeded"]
    return [yaml.safe_load((SCENARIOS / f"{n}.yaml").read_text()) for n in names]


def probe(url: str, headers: dict[str, str], job_id: str, stop: Any, out: Any) -> None:
    """Separate process: time GET /health and GET /plans/{job_id} every 50 ms until ``stop`` is set.

    A process of its own, so that the clients' JSON parsing (their GIL) does not distort the figures.
    """
    health: list[float] = []
    status: list[float] = []
    slow: list[tuple[float, float]] = []
    t_start = time.perf_counter()
    with httpx.Client(base_url=url, timeout=10, headers=headers) as c:
        while not stop.is_set():
            t = time.perf_counter()
            c.get("/api/v1/health").raise_for_status()
            health.append(time.perf_counter() - t)
            if health[-1] > 0.05:
                slow.append((t - t_start, health[-1]))
            t = time.perf_counter()
            c.get(f"/api/v1/plans/{job_id}").raise_for_status()
            status.append(time.perf_counter() - t)
            time.sleep(0.05)
    out.put((health, status, slow))


def _plan_in_process(
    scenarios: list[dict[str, Any]], order: list[int], taken: Any, start: Any, out: Any, nice: int
) -> None:
    """One in-process planner: warm up on every scenario, wait for ``start``, then take the next plan.

    The planners take plans from one shared list (``order``, the next index in ``taken``) as each is
    free, as the service's workers take queued jobs: a fixed split would leave one planner idle while
    the other plans the heavier scenarios. At the niceness the service gives its job processes
    (``nice``), so that on a shared machine both get the same share of the CPU, and with one BLAS/numba
    thread each (:data:`~planner.core.procpool.SINGLE_THREAD_ENV`, set by :func:`in_process_rate`), as
    the job workers: two planners on two cores, not four threads.
    """
    os.nice(nice)
    from planner.plan.pipeline import Planner
    from planner.scenario import resolve_scenario, scenario_from_dict

    empty = Path(tempfile.mkdtemp(prefix="cabinplan-inproc-"))

    def plan(sc: dict[str, Any]) -> float:
        t = time.perf_counter()
        Planner(resolve_scenario(scenario_from_dict(sc), base_dir=empty)).plan()
        return time.perf_counter() - t

    for sc in scenarios:  # what the service's forkserver warm-up and the cache folder give its jobs
        plan(sc)
    gc.collect()
    gc.freeze()  # as the forkserver does after its warm-up (api/warmup.py): no GC pass walks the modules
    start.wait()  # every planner warm: they plan at the same time, as the service's workers do
    t0 = time.perf_counter()
    times = []
    while True:
        with taken.get_lock():
            k = taken.value
            taken.value += 1
        if k >= len(order):
            break
        times.append((scenarios[order[k]]["name"], plan(scenarios[order[k]])))
    out.put((t0, time.perf_counter(), times))


def in_process_rate(
    scenarios: list[dict[str, Any]], n: int, planners: int
) -> tuple[float, dict[str, list[float]]]:
    """Plans a minute of ``planners`` warm in-process planners on plans ``k % len(scenarios)``, k < n.

    Returns the rate (from the common start to the last plan's end) and each scenario's plan times [s]
    (resolve + plan, no document).
    """
    mp = multiprocessing.get_context("spawn")
    start, out, taken = mp.Barrier(planners), mp.Queue(), mp.Value("i", 0)
    nice = int(os.environ.get("CABINPLAN_WORKER_NICE", Settings.model_fields["worker_nice"].default))
    order = [k % len(scenarios) for k in range(n)]
    procs = [
        mp.Process(target=_plan_in_process, args=(scenarios, order, taken, start, out, nice))
        for _ in range(planners)
    ]
    saved = {k: os.environ.get(k) for k in SINGLE_THREAD_ENV}
    os.environ.update(SINGLE_THREAD_ENV)  # one BLAS/numba thread a planner, as the service's job workers
    try:
        for p in procs:
            p.start()
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    results = [out.get(timeout=1800) for _ in procs]
    for p in procs:
        p.join()
    wall = max(r[1] for r in results) - min(r[0] for r in results)  # perf_counter: one clock per machine
    times: dict[str, list[float]] = {}
    for _, _, ts in results:
        for name, dt in ts:
            times.setdefault(name, []).append(dt)
    return 60.0 * n / wall, times


def _head(body: bytes) -> dict[str, Any]:
    """The job document of a ``GET /plans/{id}`` answer without its result (status, times, ...).

    The server writes the job's fields first and its result document last (``,"result":...}``,
    :func:`api.routes.jobroutes.job_answer`), so the head parses alone; the clients parse the 2.5-5 MB
    results after the load (orjson: 15-20 ms each here), since a plant's clients run on machines of
    their own, not on the service's two cores.
    """
    cut = body.find(b',"result":')
    return dict(orjson.loads(body[:cut] + b"}" if cut > 0 else body))


def _group_rss(pgid: int) -> list[tuple[str, int]]:
    """(role, resident set size [bytes]) of every process in the process group ``pgid`` (Linux).

    Roles: ``server`` (the group leader), ``forkserver`` and ``helper`` (its children: the forkserver,
    multiprocessing's resource tracker), ``worker`` (the forkserver's children).
    """
    procs = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[2]) != pgid:  # after the name: state, ppid, pgrp
                continue
            pages = int((stat.parent / "statm").read_text().split()[1])
        except (OSError, IndexError, ValueError):
            continue
        procs[int(stat.parent.name)] = (int(fields[1]), pages * os.sysconf("SC_PAGE_SIZE"))
    roles = {pgid: "server"}
    for p, (pp, _) in procs.items():
        if pp == pgid:
            cmd = Path(f"/proc/{p}/cmdline").read_bytes() if Path(f"/proc/{p}/cmdline").exists() else b""
            roles[p] = "forkserver" if b"forkserver" in cmd else "helper"
    return sorted((roles.get(p, "worker"), rss) for p, (_, rss) in procs.items())


def _cpu_s(pid: int) -> float:
    """CPU time [s] (user + system) process ``pid`` has used so far (Linux ``/proc/<pid>/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime


def _pct(values: list[float]) -> str:
    a = 1e3 * np.asarray(values)
    p50, p95 = np.percentile(a, 50), np.percentile(a, 95)
    return f"p50 {p50:7.1f} ms  p95 {p95:7.1f} ms  max {a.max():7.1f} ms  (n={len(a)})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--rounds", type=int, default=3, help="plans each client submits, one after another (default 3)"
    )
    args = ap.parse_args()

    load_start = os.getloadavg()
    scenarios = reference_scenarios()
    before_rate, inproc_times = in_process_rate(scenarios, args.clients * args.rounds, args.workers)

    data = Path(tempfile.mkdtemp(prefix="cabinplan-load-"))
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    env = {
        **os.environ,
        "CABINPLAN_DATA_DIR": str(data),
        "CABINPLAN_PORT": str(port),
        "CABINPLAN_WORKERS": str(args.workers),
        "CABINPLAN_TENANT_MAX_ACTIVE_JOBS": str(args.clients + 1),
        "CABINPLAN_RATE_LIMIT": "100000 per 1 second",  # the clients poll faster than a tenant may
    }
    log = (data / "server.log").open("wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", "api"], cwd=ROOT, env=env, stdout=log, stderr=log, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 300  # /ready waits for the job forkserver's warm-up
        while True:
            try:
                if httpx.get(f"{url}/api/v1/ready", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline or proc.poll() is not None:
                raise SystemExit(f"server did not start; see {data / 'server.log'}")
            time.sleep(0.1)
        headers = {"X-API-Key": (data / "local-api-key").read_text().strip()}
        idle_post_s: list[float] = []
        with httpx.Client(base_url=url, timeout=60, headers=headers) as c:
            for k in range(2 * len(scenarios)):
                t = time.perf_counter()
                r = c.post("/api/v1/plans", json=scenarios[k % len(scenarios)])
                idle_post_s.append(time.perf_counter() - t)
                r.raise_for_status()
                c.delete(f"/api/v1/plans/{r.json()['id']}")
        post_s: list[float] = []
        status_s: list[float] = []
        results: list[dict[str, Any]] = []
        lock = threading.Lock()
        # the prober's status calls go to a job of their own (cancelled at once: a small document)
        probe_job = httpx.post(f"{url}/api/v1/plans", json=scenarios[0], headers=headers, timeout=30).json()[
            "id"
        ]
        httpx.delete(f"{url}/api/v1/plans/{probe_job}", headers=headers, timeout=30)
        mp = multiprocessing.get_context("spawn")
        stop, out = mp.Event(), mp.Queue()
        prober = mp.Process(target=probe, args=(url, headers, probe_job, stop, out))
        prober.start()
        assert prober.pid is not None
        prober_pid = prober.pid
        time.sleep(2.0)  # the prober's interpreter is up before the load starts

        # Each client's HTTP session is made before the load starts, as a plant's client holds one for
        # its lifetime: making 20 (an SSL context each, though the URL is plain HTTP) costs 0.3 s of CPU,
        # which inside the measured window delayed the first submissions while the workers stood idle.
        sessions = [httpx.Client(base_url=url, timeout=60, headers=headers) for _ in range(args.clients)]

        def client(k: int) -> None:
            with sessions[k] as c:
                for rnd in range(args.rounds):  # one plan after another, each to its end
                    n = k + rnd * args.clients
                    sc = scenarios[n % len(scenarios)]
                    t = time.perf_counter()
                    r = c.post("/api/v1/plans", json=sc, headers={"Idempotency-Key": f"load-{n}"})
                    if rnd == 0:  # the first round's submissions come all at once
                        with lock:
                            post_s.append(time.perf_counter() - t)
                    r.raise_for_status()
                    job_id = r.json()["id"]
                    while True:  # long poll: each read waits up to 30 s for the plan to end
                        t = time.perf_counter()
                        body = c.get(f"/api/v1/plans/{job_id}", params={"wait_s": 30}).content
                        with lock:
                            status_s.append(time.perf_counter() - t)
                        if _head(body)["status"] not in ("queued", "running"):
                            break
                    with lock:
                        results.append({"scenario": sc, "body": body})

        cpu0 = _cpu_s(proc.pid), time.process_time(), _cpu_s(prober_pid)
        t0 = time.perf_counter()
        threads = [threading.Thread(target=client, args=(k,)) for k in range(args.clients)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        wall = time.perf_counter() - t0
        server_cpu, clients_cpu = _cpu_s(proc.pid) - cpu0[0], time.process_time() - cpu0[1]
        prober_cpu = _cpu_s(prober_pid) - cpu0[2]
        stop.set()
        health_s, probe_status_s, slow = out.get(timeout=30)
        prober.join()
        for res in results:  # parsed after the load: a client's own work, on its own machine in a plant
            res["doc"] = orjson.loads(res.pop("body"))

        ok = [res for res in results if res["doc"]["status"] == "succeeded"]
        stored_pass = sum(bool(res["doc"]["result"]["report"]["gate"]["passed"]) for res in ok)
        regate = 0
        with httpx.Client(base_url=url, timeout=300, headers=headers) as c:
            for res in ok:
                body = {"scenario": res["scenario"], "profile": res["doc"]["result"]}
                rep = c.post("/api/v1/plans:validate", json=body)
                regate += bool(rep.status_code == 200 and rep.json()["passed"])
        by_name: dict[str, list[float]] = {}
        overhead: list[float] = []
        for res in ok:
            d = res["doc"]
            run_s = d["finished_at"] - d["started_at"]
            by_name.setdefault(d["scenario"]["name"], []).append(run_s)
            overhead.append(run_s - float(d["result"]["report"]["planning_time_s"]))
        members = _group_rss(proc.pid)
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
        log.close()
    # the in-process planners again, the server gone: a VM's speed drifts over a minute (10-30% here)
    after_rate, after_times = in_process_rate(scenarios, args.clients * args.rounds, args.workers)
    for name, ts in after_times.items():
        inproc_times.setdefault(name, []).extend(ts)
    inproc_rate = 0.5 * (before_rate + after_rate)
    rate = 60 * len(results) / wall
    load_end = os.getloadavg()
    print(
        f"clients {args.clients}, {args.rounds} plans each, workers {args.workers}, "
        f"scenarios {len(scenarios)} (round robin)"
    )
    print(f"load average at start {load_start[0]:.2f}, at end {load_end[0]:.2f} (1 min)")
    print(f"wall {wall:.1f} s, {len(ok)}/{len(results)} succeeded, throughput {rate:.1f} plans/min")
    print(
        f"in process ({args.workers} warm planners, the same {len(results)} plans, before and after "
        f"the service's run): {before_rate:.1f} and {after_rate:.1f} plans/min, mean {inproc_rate:.1f}; "
        f"service / in process {rate / inproc_rate:.0%}"
    )
    for name, ts in sorted(by_name.items()):
        ip = inproc_times.get(name, [float("nan")])
        print(
            f"  {name:<22} job run time median {np.median(ts):5.2f} s (n={len(ts)}); "
            f"in process {np.median(ip):5.2f} s (n={len(ip)})"
        )
    print(
        f"  job overhead (run time, claim to stored outcome, minus the job's own planning_time_s): "
        f"median {1e3 * np.median(overhead):.0f} ms, p95 {1e3 * np.percentile(overhead, 95):.0f} ms "
        f"(n={len(overhead)})"
    )
    print(
        f"  CPU time during the load, besides the jobs: server {server_cpu:.1f} s, the clients "
        f"{clients_cpu:.1f} s, the prober {prober_cpu:.1f} s (of {2 * wall:.1f} core-seconds)"
    )
    print(
        "  service processes after the run (server, forkserver, job workers): "
        + ", ".join(f"{name} {rss / 1e6:.0f} MB" for name, rss in members)
    )
    failed = [
        (r["doc"]["scenario"]["name"], r["doc"]["reason"])
        for r in results
        if r["doc"]["status"] != "succeeded"
    ]
    if failed:
        print(f"  not succeeded: {failed}")
    print(f"GET /health under load (prober process):       {_pct(health_s)}")
    print(f"GET /plans/{{id}} under load (prober process):  {_pct(probe_status_s)}")
    late = ", ".join(f"{1e3 * dt:.0f} ms at {t:.1f} s" for t, dt in slow[:8])
    more = " ..." if len(slow) > 8 else ""
    print(f"  /health calls above 50 ms: {len(slow)} of {len(health_s)} ({late}{more})")
    print(
        f"GET /plans/{{id}}?wait_s=30 of the {args.clients} clients (long polls, {len(status_s)} "
        f"for {len(results)} plans; each waits for its plan): {_pct(status_s)}"
    )
    print(f"POST /plans idle (one at a time):               {_pct(idle_post_s)}")
    print(f"POST /plans under load (first round: {args.clients} at once): {_pct(post_s)}")
    print(f"  median under load / idle: {np.median(post_s) / np.median(idle_post_s):.1f}x")
    print(
        f"gate: {stored_pass}/{len(ok)} stored reports passed, {regate}/{len(ok)} passed POST /plans:validate"
    )


if __name__ == "__main__":
    main()
