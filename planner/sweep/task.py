"""What one plan process runs: a scenario in, an outcome out (plain data, picklable, JSON-able).

The same function runs in an embedded pool worker (:class:`~planner.sweep.run.EmbeddedExecutor`) and in a
Ray task (:class:`~planner.sweep.run.RayExecutor`), so both ways give the same results. Mesh files reach
the process as paths (embedded: the files are local) or as bytes (Ray: the driver reads each mesh once
and puts it into the object store, so cluster nodes need no shared file system).
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

from planner.core.exceptions import PlannerError
from planner.sweep.results import atomic_write, evidence_text

_LOG = logging.getLogger(__name__)

R = TypeVar("R")


def mesh_resolver(meshes: dict[str, Any] | None) -> Any:
    """A mesh resolver over name -> file path or bytes (Ray's object store), or None without meshes."""
    if not meshes:
        return None

    def resolve(name: str) -> Path | bytes | None:
        found = meshes.get(name)
        if found is None:
            return None
        return found if isinstance(found, bytes) else Path(found)

    return resolve


def plan_outcome(task: dict[str, Any], meshes: dict[str, Any] | None = None) -> dict[str, Any]:
    """Resolve and plan one scenario; the outcome of the plan, success or refusal.

    Args:
        task: ``{"scenario": dict, "base_dir": str | None}`` (the scenario of one sweep plan), and
            optionally ``"profile_path"``: the document is then written there by this process (atomic,
            fsynced) instead of being returned, so that megabytes of profile need not cross a pipe and the
            driver's single thread does not serialise every plan's file write.
        meshes: Mesh name -> file path or file bytes, looked up before the default resolution.

    Returns:
        ``{"status": "succeeded" | "failed", "reason", "message", "evidence" (JSON text of the refusal
        details), "duration_s", "lower_bound_ratio", "min_clearance_m", "min_clearance_bound_m",
        "peak_force_ratio",
        "planning_time_s" (the planner's own clock), "task_time_s" (resolution + planning, this process),
        "document" (JSON text of the profile or the refusal document; ``None`` once written to
        ``profile_path``), "profile_written" (bool), "pid"}``. Numbers are ``None`` where a refusal has
        none. An unexpected exception is an ``internal_error`` outcome, never raised.
    """
    from planner.documents.output import refusal_document, result_document
    from planner.plan.pipeline import Planner
    from planner.scenario import ResolvedScenario, resolve_scenario, scenario_from_dict

    def resolve() -> ResolvedScenario:
        spec = scenario_from_dict(task["scenario"], source="sweep plan")
        base_dir = Path(task["base_dir"]) if task.get("base_dir") else None
        return resolve_scenario(spec, base_dir=base_dir, mesh_resolver=mesh_resolver(meshes))

    def plan(sc: ResolvedScenario) -> tuple[dict[str, Any], str]:
        planner = Planner(sc)
        t_plan = time.perf_counter()
        result = planner.plan()
        report = result.report
        fields = {
            "message": f"{result.profile.duration_s:.3f} s, {len(result.profile.t)} samples",
            "duration_s": float(result.profile.duration_s),
            "lower_bound_ratio": float(report["duration_ratio"]),
            "min_clearance_m": float(result.gate.min_clearance_m),
            "min_clearance_bound_m": _float_or_none(result.gate.min_clearance_bound_m),
            "peak_force_ratio": float(result.gate.peak_ratios["effort"]),
            "planning_time_s": float(report.get("planning_time_s", time.perf_counter() - t_plan)),
        }
        return fields, json.dumps(result_document(sc, result))

    name = task["scenario"].get("name")
    return task_outcome(
        task,
        f"sweep plan {name}",
        resolve,
        plan,
        lambda exc, sc: refusal_document(exc, sc, name=name),
        ("duration_s", "lower_bound_ratio", "min_clearance_m", "min_clearance_bound_m", "peak_force_ratio"),
    )


def task_outcome(
    task: dict[str, Any],
    what: str,
    resolve: Callable[[], R],
    plan: Callable[[R], tuple[dict[str, Any], str]],
    refusal: Callable[[PlannerError, R | None], dict[str, Any]],
    numbers: tuple[str, ...],
) -> dict[str, Any]:
    """The outcome of one task, success or refusal, never an exception: the shape every runner returns.

    One shape for a sweep's plans and a campaign's cycles, so the driver records both the same way:
    ``{"status": "succeeded" | "failed", "reason", "message", "evidence" (JSON text of the refusal's
    details), *numbers, "planning_time_s", "task_time_s" (resolution + planning, this process), "document"
    (JSON text; ``None`` once written to the task's ``profile_path``, :func:`deliver`), "profile_written",
    "pid"}``. A refusal (:class:`PlannerError`) leaves the numbers ``None`` and delivers its refusal
    document; any other exception is an ``internal_error`` outcome without a document (logged).

    Args:
        task: The task (its ``profile_path``, if any).
        what: The task in the log's line of a crash ("sweep plan <name>").
        resolve: Validates and resolves the task's input.
        plan: Plans the resolved input: the outcome's fields (``message``, the numbers,
            ``planning_time_s``) and the document's JSON text.
        refusal: The refusal document of an error and the resolved input (None: it did not resolve).
        numbers: The runner's own numeric fields, in the order the outcome lists them.
    """
    t0 = time.perf_counter()
    out: dict[str, Any] = {
        "status": "failed",
        "reason": None,
        "message": None,
        "evidence": None,
        **dict.fromkeys(numbers),
        "planning_time_s": None,
        "task_time_s": None,
        "document": None,
        "profile_written": False,
        "pid": os.getpid(),
    }
    resolved: R | None = None
    try:
        resolved = resolve()
        fields, document = plan(resolved)
    except PlannerError as exc:
        doc = refusal(exc, resolved)
        out.update(reason=exc.reason, message=exc.message, evidence=evidence_text(doc.get("details", {})))
        document = json.dumps(doc)
    except Exception as exc:  # a bug: recorded as the task's outcome, the sweep or campaign goes on
        _LOG.exception("%s crashed", what)
        out.update(reason="internal_error", message=f"internal error: {type(exc).__name__}: {exc}")
        out["task_time_s"] = time.perf_counter() - t0
        return out
    else:
        out.update(status="succeeded", **fields)
    deliver(out, task, document)
    out["task_time_s"] = time.perf_counter() - t0
    return out


def deliver(out: dict[str, Any], task: dict[str, Any], document: str) -> None:
    """Write the document to the task's ``profile_path`` if it has one, else put it into the outcome."""
    path = task.get("profile_path")
    if not path:
        out["document"] = document
        return
    try:
        atomic_write(Path(path), document + "\n")
    except OSError as exc:  # the driver writes it then (and reports a lasting error itself)
        _LOG.warning("profile %s: cannot write (%s); handed to the driver", path, exc.strerror)
        out["document"] = document
        return
    out["profile_written"] = True


#: A task's runner: ``(task, meshes) -> outcome`` (plain data, as :func:`plan_outcome` returns).
Runner = Callable[[dict[str, Any], dict[str, Any] | None], dict[str, Any]]

#: The task key naming another runner than :func:`plan_outcome`, as ``"package.module:function"``.
RUNNER_KEY = "runner"
#: Modules a task may name its runner in (a task is data: it never names arbitrary code).
RUNNER_PACKAGES = ("planner.",)


def task_runner(task: dict[str, Any]) -> Runner:
    """The function that runs ``task``: :func:`plan_outcome`, or the one ``task["runner"]`` holds.

    The executors run any kind of independent plan the same way (a sweep's plans, a campaign's cycles):
    the task carries its runner, a module-level function of the planner package, pickled by reference
    into the plan process (the embedded pool and its warm-up file, Ray alike). The executors themselves
    import no layer above this one: the layer that makes the tasks hands over the function.

    Raises:
        InvalidInput: the runner is not a function of the planner package.
    """
    runner = task.get(RUNNER_KEY)
    if runner is None:
        return plan_outcome
    if not callable(runner) or not str(getattr(runner, "__module__", "")).startswith(RUNNER_PACKAGES):
        from planner.core.exceptions import InvalidInput

        raise InvalidInput(
            f"task.runner: expected a function of the planner package, got {runner!r}", field="task.runner"
        )
    return cast(Runner, runner)


def run_task(task: dict[str, Any], meshes: dict[str, Any] | None = None) -> dict[str, Any]:
    """Run one task with its runner (:func:`task_runner`); the outcome, never an exception.

    A runner that cannot be found is an ``internal_error`` outcome (the driver records it like any other).
    """
    try:
        runner = task_runner(task)
    except (PlannerError, ImportError, AttributeError) as exc:
        return {
            "status": "failed",
            "reason": "internal_error",
            "message": f"internal error: task runner {task.get(RUNNER_KEY)!r}: {exc}",
            "document": None,
            "pid": os.getpid(),
        }
    return runner(task, meshes)


def warm_up(task: dict[str, Any] | None, meshes: dict[str, Any] | None = None) -> float:
    """Import the planner and plan ``task`` once (result discarded), so later plans start warm; seconds.

    Planning the first plan of the sweep compiles or loads every kernel a plan uses and builds the
    cabin's clearance grid, which processes forked afterwards inherit.
    """
    t0 = time.perf_counter()
    import planner.plan.pipeline  # noqa: F401  (the import is the point)

    if task is not None:
        try:
            run_task(task, meshes)
        except Exception:  # a failed warm-up only makes the first plans slower
            _LOG.exception("sweep warm-up failed")
    return time.perf_counter() - t0


__all__ = [
    "RUNNER_KEY",
    "Runner",
    "deliver",
    "mesh_resolver",
    "plan_outcome",
    "run_task",
    "task_outcome",
    "task_runner",
    "warm_up",
]


def _float_or_none(value: float | None) -> float | None:
    """A float for the table, None where the report has none."""
    return None if value is None else float(value)
