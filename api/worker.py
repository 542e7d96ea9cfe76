"""The child side of a job: runs in a warm worker process, talks to the parent through a pipe; and plan files.

A job worker is a reused process (:class:`planner.core.procpool.WarmPool`, see :mod:`api.jobs`): it arms
its parent-death signal and lowers its priority once (:func:`worker_setup`), so it ends with the service
(:mod:`planner.core.lifeline`) and yields the CPU to the event loop; then it runs one job after another
(:func:`run_job`). The parent sends the job description (its kind's function, the scenario as submitted
and the tenant's mesh files it names) on the pipe. The worker runs that function (``runner``,
:mod:`api.jobkinds`; :func:`plan_job` for plans), sends ``("progress", stage, fraction, detail)``
messages while planning (``detail``: ``None``, or a campaign's units), ``("keep", name, bytes)`` for
what a relaunch must not redo (a campaign's finished cycles) and one ``("done", outcome)`` at the end of
each job; the parent writes everything to the database. The packed result document (:mod:`api.compact`)
and its JSON (kept by the server for the first reads, :mod:`api.results`) are made here, never in
the server; the packed document is the only thing a job writes: the CSV and the plot
are made on request (:func:`profile_csv`, :func:`plot_png`, run by the server in its thread pool, the
plot kept once made).

What a worker keeps from one job to the next is what the planner caches by content: imports, compiled
kernels, parsed meshes and a cabin's collision geometry (keyed by the mesh's content hash). Every job
resolves its scenario afresh and seeds its own random generators, so a reused worker plans exactly what
a fresh process plans (tests/api/test_warm_workers.py).

The planner is imported inside the functions (the first job, or the forkserver's warm-up,
:mod:`api.warmup`, imports it once and every worker forks warm), so the server can name these functions
(:mod:`api.jobkinds`) without importing the planner.
"""

from __future__ import annotations

import logging
import os
import threading
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING, Any

from api.compact import document_json, pack_value
from api.jobtypes import FileSource
from planner.core.lifeline import die_with_parent
from planner.core.startup import tune_allocator

if TYPE_CHECKING:
    from planner.core.exceptions import PlannerError
    from planner.scenario.resolve import ResolvedScenario
    from planner.timing.profile import DriveProfile

_LOG = logging.getLogger(__name__)


def plan_job(job: dict[str, Any], send: Any) -> dict[str, Any]:
    """Plan one job; the outcome ``{"status", "reason", "message", "document", "provenance"}``.

    The document is the result (or refusal) document as a dict, its samples as numpy arrays (packed and
    written as they are, :func:`run_job`: no list of ~10^5 Python floats); nothing else is made here (the CSV
    and the plot are made on request from the stored document: :func:`profile_csv`, :func:`plot_png`).

    Args:
        job: ``{"id", "scenario" (dict as submitted), "meshes" ({id: path}), "empty_dir"}``.
        send: Called with ``(stage, fraction)`` as the planner's stages start.
    """
    from api.store import scenario_mesh_resolver
    from planner.core.exceptions import PlannerError
    from planner.documents.output import refusal_document, result_document
    from planner.plan.pipeline import Planner
    from planner.scenario.resolve import resolve_scenario
    from planner.scenario.schema import scenario_from_dict

    sc: ResolvedScenario | None = None
    try:
        spec = scenario_from_dict(job["scenario"], source="scenario")
        sc = resolve_scenario(
            spec, base_dir=Path(job["empty_dir"]), mesh_resolver=scenario_mesh_resolver(job["meshes"])
        )
        planner = Planner(sc, send)
        result = planner.plan()
    except PlannerError as exc:
        name = job["scenario"].get("name") if isinstance(job["scenario"], dict) else None
        return failed_outcome(exc, refusal_document(exc, sc, name=name))
    message = f"{sc.spec.name}: {result.profile.duration_s:.3f} s, {len(result.profile.t)} samples"
    return succeeded_outcome(result_document(sc, result, arrays=True), message)


def worker_setup(server_pid: int | None, nice: int) -> None:
    """Once in each job worker, before its first job: die with the service, and lower the priority.

    Args:
        server_pid: The service's pid (:func:`planner.core.lifeline.die_with_parent`).
        nice: Niceness added to the process (once: :func:`os.nice` adds up), so planning yields the CPU
            to the service's event loop.
    """
    die_with_parent(server_pid)
    tune_allocator()
    if nice:
        os.nice(int(nice))


def run_job(job: dict[str, Any], conn: Connection) -> None:
    """Run one ``job`` in this worker (its kind's function) and send its progress and its outcome.

    The outcome (always sent, last) carries the result document packed (``packed``,
    :func:`api.compact.pack_value`: what is stored) and as its JSON (``json``, bytes,
    :func:`api.compact.document_json`: what the server keeps for the first reads); a bug in the job's
    function is a failed job with reason ``internal_error``, and the worker takes the next job.
    """

    def send(message: tuple[Any, ...]) -> None:
        try:
            conn.send(message)
        except OSError:  # the server is gone (its end of the pipe closed): its lease re-queues the job
            os._exit(0)  # quietly, before the parent-death signal: no traceback in the server's log

    class Progress:
        """What the job's function reports through: ``(stage, fraction[, detail])``, and files to keep."""

        def __call__(self, stage: str, fraction: float, detail: dict[str, Any] | None = None) -> None:
            send(("progress", str(stage), float(fraction), detail))

        def keep(self, name: str, data: bytes) -> None:
            send(("keep", str(name), bytes(data)))

    progress = Progress()

    try:
        outcome = job["runner"](job, progress)
    except Exception as exc:  # a bug in the planner: report it as a failed job, never hang
        _LOG.exception("job %s crashed", job.get("id"))
        outcome = {
            "status": "failed",
            "reason": "internal_error",
            "message": f"internal error: {type(exc).__name__}: {exc}",
            "document": None,
        }
    document = outcome.pop("document", None)
    outcome["packed"] = pack_value(document) if document is not None else None
    outcome["json"] = document_json(document) if document is not None else None
    send(("done", outcome))


# ---------------------------------------------------------------- files made on request (server side)
_PLOT_LOCK = threading.Lock()


def _resolved(source: FileSource) -> ResolvedScenario:
    from api.store import scenario_mesh_resolver
    from planner.scenario.resolve import resolve_scenario
    from planner.scenario.schema import scenario_from_dict

    spec = scenario_from_dict(source.input, source="plan")
    return resolve_scenario(
        spec, base_dir=Path(source.empty_dir), mesh_resolver=scenario_mesh_resolver(source.meshes)
    )


def profile_csv(source: FileSource) -> bytes:
    """The drive profile of a succeeded plan as CSV (``t_s``, then position, velocity, ... per drive)."""
    from planner.robots import load_robot
    from planner.robots.cabin8 import Cabin8
    from planner.timing.profile import DriveProfile

    robot = load_robot(str(source.document["robot"]))
    if not isinstance(robot, Cabin8):  # planning jobs are cabin8 plans
        raise ValueError(f"no drive profile CSV for robot {robot.name!r}")
    return DriveProfile.from_dict(source.document, robot).to_csv().encode()


def plot_png(source: FileSource) -> bytes:
    """The plot of a succeeded plan: the profile against its limits, the clearance and the deflection.

    As the planner's own plot (:func:`planner.documents.plot.plan_png`): the clearance is the exact
    distance (:meth:`CollisionWorld.clearance_profile`) at about 200 samples (every ``N // 200``-th and
    the last); the deflection is the report's predicted series (``report.deflection.along``, model
    predictions at up to 100 samples) drawn through the profile's samples.
    """
    from planner.timing.profile import DriveProfile

    sc = _resolved(source)
    doc = source.document
    profile = DriveProfile.from_dict(doc, sc.robot)
    with _PLOT_LOCK:  # pyplot's figure registry is global: one plot at a time per server process
        return _plot(sc, doc, profile)


def _plot(sc: ResolvedScenario, doc: dict[str, Any], profile: DriveProfile) -> bytes:
    import numpy as np

    from planner.collision.world import CollisionWorld
    from planner.documents.plot import profile_png

    q = profile.joints
    idx = np.unique(np.concatenate([np.arange(0, len(q), max(1, len(q) // 200)), [len(q) - 1]]))
    clearance = None
    if sc.cabin is not None:
        clearance = CollisionWorld(sc.robot, sc.cabin, sc.payload).clearance_profile(q[idx])
    deflection = None
    along = ((doc.get("report") or {}).get("deflection") or {}).get("along")
    if along and along.get("t_s"):
        t_s = np.asarray(along["t_s"], dtype=float)
        x = np.hstack([np.asarray(along["translation_m"]), np.asarray(along["rotation_rad"])])
        deflection = np.column_stack([np.interp(profile.t, t_s, x[:, j]) for j in range(6)])
    return profile_png(
        profile,
        sc.robot,
        profile.t[idx],
        clearance,
        sc.options.clearance_m,
        title=f"{sc.spec.name}: {profile.duration_s:.2f} s",
        deflection=deflection,
    )


__all__ = ["plan_job", "plot_png", "profile_csv", "run_job", "worker_setup"]


def succeeded_outcome(document: dict[str, Any], message: str) -> dict[str, Any]:
    """A job's outcome for a result: its one-line message, and its result document (with provenance)."""
    return {
        "status": "succeeded",
        "reason": None,
        "message": message,
        "document": document,
        "provenance": document["provenance"],
    }


def failed_outcome(exc: PlannerError, document: dict[str, Any]) -> dict[str, Any]:
    """A job's outcome for a refusal: its reason and message, and its refusal document (with provenance)."""
    return {
        "status": "failed",
        "reason": exc.reason,
        "message": exc.message,
        "document": document,
        "provenance": document.get("provenance"),
    }
