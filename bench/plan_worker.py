"""Plan scenario files in a worker process of any checkout: ``plan_file`` and a JSON-lines loop.

:func:`plan_file` plans one scenario file with the default options (or some overridden), re-checks the
returned profile by the independent gate route (``planner.gate.check_profile``, world and requirements
rebuilt from the scenario file) after a JSON round trip, and returns a JSON-able record. It imports the
planner lazily, so whichever ``planner`` is first on the path plans.

Run as a script (``python bench/plan_worker.py`` with ``PYTHONPATH=<checkout>``), it reads one job a line
on stdin (``{"path": ..., "options": {...} | null}``) and answers one record a line; the planner's own
output to stdout is sent to stderr, so the answers stay one JSON document a line. The generalisation
benchmark runs one such worker per checkout (this tree and ``--baseline-repo``), so both plan the same
files in the same run.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any


def _report_fields(rep: dict[str, Any]) -> dict[str, Any]:
    return {
        "planning_time_s": float(rep["planning_time_s"]),
        "single_drive_lower_bound_s": float(rep["single_drive_lower_bound_s"]),
        "duration_ratio": float(rep["duration_ratio"]),
        "staged_duration_ratio": float(rep.get("staged_duration_ratio", rep["duration_ratio"])),
        "search": (rep.get("search") or {}).get("method"),
        "stages_s": {k: float(v) for k, v in (rep.get("stages_s") or {}).items()},
    }


def plan_file(path: str, options: dict[str, Any] | None = None) -> dict[str, Any]:
    """Plan one scenario file (options overridden), re-check the profile by the independent gate route.

    Never raises for a refusal or a crash: the record says ``ok``, ``reason``, ``message`` and ``wall_s``
    (and, when planned, the report's figures, ``stages_s``, the gate's verdict and the re-check's).
    """
    from planner.core.exceptions import PlannerError
    from planner.documents.output import result_document
    from planner.gate.check_profile import check_profile
    from planner.plan.pipeline import plan_scenario as plan
    from planner.scenario import load_scenario_file, resolve_scenario

    out: dict[str, Any] = {"options": options or {}}
    t0 = time.perf_counter()
    try:
        spec = load_scenario_file(Path(path))
        if options:
            spec = spec.model_copy(update={"options": spec.options.model_copy(update=options)})
        sc = resolve_scenario(spec, base_dir=Path(path).parent)
        t0 = time.perf_counter()
        res = plan(sc)
    except PlannerError as exc:
        out.update(ok=False, reason=exc.reason, message=exc.message, wall_s=time.perf_counter() - t0)
        return out
    except Exception as exc:  # a crash is a result too (and a bug)
        out.update(ok=False, reason=f"error:{type(exc).__name__}", message=str(exc))
        out["wall_s"] = time.perf_counter() - t0
        return out
    out.update(
        ok=True,
        reason=None,
        wall_s=time.perf_counter() - t0,
        duration_s=float(res.profile.duration_s),
        min_clearance_m=float(res.gate.min_clearance_m),
        gate_passed=bool(res.gate.passed),
        # as bench.ompl_log.path_length (this file runs in other checkouts too): Euclidean drive steps
        path_length=float(
            sum(math.dist(a, b) for a, b in zip(res.profile.position, res.profile.position[1:], strict=False))
        ),
        **_report_fields(res.report),
    )
    doc = json.loads(json.dumps(result_document(sc, res)))
    recheck = check_profile(sc, doc)
    out.update(recheck_passed=bool(recheck.passed), recheck_summary=recheck.summary())
    return out


def serve() -> None:
    """Answer jobs from stdin, one JSON line each, until stdin closes."""
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # anything the planner prints goes to stderr
    for line in sys.stdin:
        if line.strip():
            job = json.loads(line)
            answers.write(json.dumps(plan_file(job["path"], job.get("options")), default=float) + "\n")


if __name__ == "__main__":
    serve()
