"""Running a campaign: its cycles on the sweep executors, the cycle journal as cache, the outputs.

The campaign's cycles (:mod:`planner.task.campaign`) are independent plans: they run on the sweep
executors (:mod:`planner.sweep.run`: embedded warm workers or Ray, through the one driver loop
:func:`~planner.sweep.run.drive`), each as a task run by :func:`planner.campaign.worker.cycle_outcome`.
Every finished cycle is a row of the journal (:class:`planner.sweep.results.Journal`, keyed by the cycle's
hash), appended and fsynced once its document is in place: a run killed at any point, even by SIGKILL,
keeps every cycle it finished, and the next run plans only the cycles without a row.

* ``order: given`` (:meth:`CampaignRun.given`): the cycles of the listed order run in parallel (cycle k's
  cabin holds units 0..k-1, whatever their plans did); no cycle after the first refused one is started,
  and the refusal's evidence says what blocks it.
* ``order: find`` (:meth:`CampaignRun.find`): the order search (:func:`planner.task.order.find_order`),
  each of its batches planned in parallel.

The output folder::

    OUT_DIR/cycles/results.jsonl      the journal: one row per planned cycle, keyed by its hash (resume)
    OUT_DIR/cycles/profiles/NAME.json each cycle's document (profile or refusal), written by its process
    OUT_DIR/cycles/scenarios/NAME.json each composed cycle document (``cabinplan cycle`` re-runs it)
    OUT_DIR/NN-ID.json                the cycle documents in install order (NN from 01)
    OUT_DIR/NN-ID.refused.json        the first refused cycle of a given order (its refusal document)
    OUT_DIR/summary.json              order, per-unit status, durations, the campaign's time, evidence
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from planner.campaign.worker import cycle_outcome
from planner.core.exceptions import InvalidInput
from planner.sweep.results import Journal, atomic_write
from planner.sweep.run import Executor, Job, drive
from planner.task.campaign import (
    MONOTONICITY,
    CycleJob,
    blocking_message,
    campaign_sha256,
    cycle_document,
    cycle_key,
    ordinal,
    verdict_of,
)
from planner.task.campaign_schema import Campaign
from planner.task.evidence import Mention
from planner.task.order import FindResult, Query, Verdict, find_order

_LOG = logging.getLogger(__name__)

__all__ = [
    "CYCLE_RUNNER",
    "CampaignResult",
    "CampaignRun",
    "UnitStatus",
    "campaign_meshes",
    "write_outputs",
]

#: The executors' runner of one campaign cycle (:func:`planner.sweep.task.task_runner`).
CYCLE_RUNNER = cycle_outcome


@dataclass
class UnitStatus:
    """Where one unit stands in a run (the progress bar's row and the summary's entry).

    ``status``: ``waiting`` | ``planning`` | ``planned`` | ``refused`` | ``not_planned``.
    """

    unit: str
    status: str = "waiting"
    cycles_planned: int = 0
    cycles_cached: int = 0
    message: str = ""


Progress = Callable[[dict[str, UnitStatus]], None]


@dataclass
class CampaignResult:
    """The outcome of a campaign run (what :func:`write_outputs` writes as ``summary.json``)."""

    order: list[str]
    succeeded: bool
    units: list[dict[str, Any]]
    message: str
    search: dict[str, Any] | None = None
    cycles_planned: int = 0
    cycles_cached: int = 0
    wall_time_s: float = 0.0


class CampaignRun:
    """One run of a campaign on an executor, with the cycle journal of ``out_dir`` as its cache.

    Args:
        campaign: The validated campaign.
        out_dir: The output folder (created; a killed run's folder resumes).
        executor: Where cycles run (embedded workers, Ray, or in process); the caller closes it. ``None``
            until it is set (:attr:`executor`): the journal can be read before any worker starts.
        base_dir: Folder the campaign's relative mesh paths refer to.
        progress: Called with every unit's status whenever one changes.
        poll_s: Longest wait for outcomes before the progress is refreshed [s].
    """

    def __init__(
        self,
        campaign: Campaign,
        out_dir: Path,
        executor: Executor | None,
        *,
        base_dir: Path | None = None,
        progress: Progress | None = None,
        poll_s: float = 0.2,
    ) -> None:
        self.campaign = campaign
        self.out_dir = Path(out_dir)
        self.executor = executor
        self.base_dir = Path(base_dir).resolve() if base_dir is not None else None
        self.journal = Journal(self.out_dir / "cycles")
        self.status = {u: UnitStatus(u) for u in campaign.ids}
        self._progress = progress or (lambda s: None)
        self.poll_s = poll_s
        #: Cycles this run planned, and those it found planned by an earlier run (the journal's rows then).
        self.planned = 0
        self.cached = 0
        self._known = frozenset(self.journal.rows)
        self._counted: set[str] = set()
        self._initial = {e.id for e in campaign.installed}

    # ----------------------------------------------------------------- jobs
    def job(self, unit: str, installed: Iterable[str]) -> CycleJob:
        """The cycle of ``unit`` after ``installed`` (composed and keyed)."""
        before = frozenset(installed)
        doc = cycle_document(self.campaign, unit, before)
        return CycleJob(unit, before, cycle_key(doc, self.base_dir), doc)

    def _task(self, job: CycleJob) -> dict[str, Any]:
        return {
            "runner": CYCLE_RUNNER,
            "cycle": job.document,
            "base_dir": str(self.base_dir) if self.base_dir else None,
            "profile_path": str(self.journal.out_dir / "profiles" / f"{job.name}.json"),
        }

    def _hard_limit_s(self, job: CycleJob) -> float:
        limits = self.campaign.limits
        budget = float(self.campaign.options.time_limit_s)
        limit = budget + float(limits.grace_s)
        if limits.wall_time_limit_s is not None:
            limit = min(limit, float(limits.wall_time_limit_s))
        return limit

    def _write_input(self, job: CycleJob) -> None:
        path = self.journal.out_dir / "scenarios" / f"{job.name}.json"
        if not path.exists():
            atomic_write(path, json.dumps(job.document, indent=1) + "\n")

    def plan(self, jobs: Sequence[CycleJob], stop_at_refusal: bool = False) -> list[dict[str, Any]]:
        """The journal rows of ``jobs`` (in their order), planning those without one.

        ``stop_at_refusal``: once a cycle is refused, the jobs after it that have not started are not
        planned (their rows are missing from the result: ``{}``); jobs already running finish and are
        recorded.
        """
        pending: deque[Job[CycleJob]] = deque()
        for job in jobs:
            if self.journal.done(job.sha256):
                if job.sha256 in self._known and job.sha256 not in self._counted:
                    self._counted.add(job.sha256)
                    self.cached += 1
                    self.status[job.unit].cycles_cached += 1
                row = self.journal.rows[job.sha256]
                if stop_at_refusal and row.get("status") != "succeeded":
                    break
                continue
            self._write_input(job)
            pending.append(Job(job, self._task(job), self._hard_limit_s(job)))
        index = {job.sha256: k for k, job in enumerate(jobs)}
        dropped: set[str] = set()

        def finished(done: Job[CycleJob], outcome: dict[str, Any], wall_time_s: float) -> None:
            c = done.plan
            row = {
                "scenario_sha256": c.sha256,
                "unit": c.unit,
                "installed": sorted(c.installed),
                "name": c.name,
                **{
                    k: outcome.get(k)
                    for k in (
                        "status",
                        "reason",
                        "message",
                        "evidence",
                        "duration_s",
                        "min_clearance_m",
                        "planning_time_s",
                    )
                },
                "wall_time_s": wall_time_s,
                "attempts": done.attempt,
                "profile_file": f"cycles/profiles/{c.name}.json"
                if outcome.get("document") or outcome.get("profile_written")
                else None,
            }
            if self.journal.record(c, row, outcome.get("document")):
                self.planned += 1
                self.status[c.unit].cycles_planned += 1
            self._mark(c.unit, "planned" if row["status"] == "succeeded" else "refused", row)
            if stop_at_refusal and row["status"] != "succeeded":
                k = index[c.sha256]
                for j in [j for j in pending if index[j.plan.sha256] > k]:
                    pending.remove(j)
                    dropped.add(j.plan.sha256)

        def running_changed(n: int) -> None:
            for u in self.status.values():
                if u.status == "planning":
                    u.status = "waiting"
            waiting = {j.plan.sha256 for j in pending} | dropped
            for j in jobs:
                if j.sha256 not in waiting and not self.journal.done(j.sha256):
                    self.status[j.unit].status = "planning"
            self._progress(self.status)

        if pending:
            if self.executor is None:
                raise RuntimeError("campaign: cycles to plan but no executor set")
            drive(pending, self.executor, finished, running_changed=running_changed, poll_s=self.poll_s)
        return [self.journal.rows.get(job.sha256, {}) for job in jobs]

    def _mark(self, unit: str, status: str, row: dict[str, Any] | None = None) -> None:
        st = self.status[unit]
        st.status = status
        if row is not None:
            st.message = str(row.get("message") or "")
        self._progress(self.status)

    # ------------------------------------------------------------- verdicts
    def verdict(self, job: CycleJob, row: dict[str, Any]) -> tuple[Verdict, dict[str, Mention]]:
        """The feasibility verdict of a planned cycle, and the installed units its refusal names."""
        details = None
        if row.get("status") != "succeeded" and row.get("profile_file"):
            try:
                doc = json.loads((self.out_dir / str(row["profile_file"])).read_text(encoding="utf-8"))
                details = doc.get("details") if isinstance(doc, dict) else None
            except (OSError, ValueError):  # the row's own evidence then
                details = None
        return verdict_of(row, job.installed, frozenset(self._initial), details)

    def oracle(self, queries: Sequence[Query]) -> list[Verdict]:
        """Answer a batch of ``feasible(unit, installed)`` queries (planned in parallel, cached by key)."""
        jobs = [self.job(u, s) for u, s in queries]
        for job in jobs:
            if not self.journal.done(job.sha256) and self.status[job.unit].status != "planned":
                self.status[job.unit].status = "waiting"
        rows = self.plan(jobs)
        return [self.verdict(job, row)[0] for job, row in zip(jobs, rows, strict=True)]

    # ------------------------------------------------------------------ orders
    def given(self) -> CampaignResult:
        """Plan the listed order; stop at the first refused cycle and name what blocks it."""
        t0 = time.monotonic()
        ids = self.campaign.ids
        jobs = [self.job(u, ids[:k]) for k, u in enumerate(ids)]
        rows = self.plan(jobs, stop_at_refusal=True)
        units, message, ok = [], "", True
        for k, (job, row) in enumerate(zip(jobs, rows, strict=True)):
            entry = self._entry(k, job, row if ok else {})
            if ok and row and row.get("status") != "succeeded":
                ok = False
                verdict, found = self.verdict(job, row)
                entry["blockers"] = sorted(verdict.blockers or ())
                entry["blocking"] = self._blocking(job, verdict, found, ids)
                message = f"unit {job.unit}, installed {ordinal(k)}: cycle refused: " + (
                    "; ".join(entry["blocking"]) or verdict.message
                )
            units.append(entry)
        if ok:
            message = f"every cycle planned in the given order ({', '.join(ids)})"
        for u in ids[len([e for e in units if e["status"] == "planned"]) :]:
            if self.status[u].status not in ("refused",):
                self.status[u].status = "not_planned"
        self._progress(self.status)
        return self._result(ids, ok, units, message, None, t0)

    def find(self) -> CampaignResult:
        """Search an order in which every cycle plans (see :mod:`planner.task.order`)."""
        t0 = time.monotonic()
        found: FindResult = find_order(
            self.campaign.ids,
            self.oracle,
            batch=max(1, int(self.executor.max_in_flight)) if self.executor is not None else 1,
            max_cycles=self.campaign.search.max_cycles,
        )
        search: dict[str, Any] = {
            "assumption": MONOTONICITY,
            "cycles_asked": len(found.verdicts),
            "states_explored": found.states_explored,
            "states_pruned": found.states_pruned,
            "exhausted": found.exhausted,
            "constraints": [{"unit": u, "before_one_of": sorted(b)} for u, b in found.constraints],
            "refusals": [
                {
                    "unit": u,
                    "installed": sorted(s),
                    "blockers": sorted(v.blockers or ()),
                    "reason": v.reason,
                    "message": v.message,
                }
                for (u, s), v in found.verdicts.items()
                if not v.feasible
            ],
        }
        if found.order is None:
            search["reason"] = found.reason
            units = [
                {"id": u, "position": None, "status": "not_planned", **self._unit_counts(u)}
                for u in self.campaign.ids
            ]
            for u in self.campaign.ids:
                self.status[u].status = "not_planned"
            self._progress(self.status)
            message = f"no install order found among those tried: {found.reason}"
            return self._result([], False, units, message, search, t0)
        jobs = [self.job(u, found.order[:k]) for k, u in enumerate(found.order)]
        rows = self.plan(jobs)  # every one is in the journal already: no plan
        units = [self._entry(k, job, row) for k, (job, row) in enumerate(zip(jobs, rows, strict=True))]
        message = f"every cycle planned in the order found ({', '.join(found.order)})"
        return self._result(found.order, True, units, message, search, t0)

    def run(self) -> CampaignResult:
        """The campaign's order mode: :meth:`given` or :meth:`find`; then :func:`write_outputs`."""
        result = self.given() if self.campaign.order == "given" else self.find()
        write_outputs(self.out_dir, self.campaign, result)
        return result

    # ---------------------------------------------------------------- helpers
    def _unit_counts(self, unit: str) -> dict[str, int]:
        st = self.status[unit]
        return {"cycles_planned": st.cycles_planned, "cycles_cached": st.cycles_cached}

    def _blocking(
        self, job: CycleJob, verdict: Verdict, found: dict[str, Mention], order: Sequence[str]
    ) -> list[str]:
        out = []
        for unit, m in found.items():
            if unit in job.installed:
                position = f"installed {ordinal(list(order).index(unit))}"
                out.append(blocking_message(job.unit, m, position, fixed=False))
            elif unit in self._initial:
                out.append(blocking_message(job.unit, m, "installed before the campaign", fixed=True))
        return out

    def _entry(self, k: int, job: CycleJob, row: dict[str, Any]) -> dict[str, Any]:
        status = "not_planned"
        if row:
            status = "planned" if row.get("status") == "succeeded" else "refused"
        self.status[job.unit].status = status
        return {
            "id": job.unit,
            "position": k + 1,
            "status": status,
            "cycle_sha256": job.sha256,
            "reason": row.get("reason"),
            "message": row.get("message"),
            "duration_s": row.get("duration_s"),
            "min_clearance_m": row.get("min_clearance_m"),
            "planning_time_s": row.get("planning_time_s"),
            "wall_time_s": row.get("wall_time_s"),
            "installed_before": sorted(job.installed),
            "source": row.get("profile_file"),
            **self._unit_counts(job.unit),
        }

    def _result(
        self,
        order: list[str],
        ok: bool,
        units: list[dict[str, Any]],
        message: str,
        search: dict[str, Any] | None,
        t0: float,
    ) -> CampaignResult:
        return CampaignResult(
            order, ok, units, message, search, self.planned, self.cached, time.monotonic() - t0
        )


# ------------------------------------------------------------------------------------------- outputs


def campaign_meshes(campaign: Campaign, base_dir: Path | None = None) -> dict[str, bytes]:
    """Bytes of every mesh file the campaign names (not the packaged reference cabins), read once (Ray).

    Raises:
        InvalidInput: a mesh file cannot be read (the field named).
    """
    from planner.meshes import reference_cabin_path

    names: list[tuple[str, str]] = []
    if reference_cabin_path(campaign.cabin.mesh) is None:
        names.append(("cabin.mesh", campaign.cabin.mesh))
    names += [(f"installed[{k}].mesh", e.mesh) for k, e in enumerate(campaign.installed) if e.mesh]
    for k, u in enumerate(campaign.units):
        if u.unit.mesh:
            names.append((f"units[{k}].unit.mesh", u.unit.mesh))
        if u.dock.fixture.mesh:
            names.append((f"units[{k}].dock.fixture.mesh", u.dock.fixture.mesh))
    out: dict[str, bytes] = {}
    for where, name in names:
        if name in out:
            continue
        path = Path(name) if Path(name).is_absolute() or base_dir is None else base_dir / name
        try:
            out[name] = path.read_bytes()
        except OSError as exc:
            raise InvalidInput(f"{where}: cannot read {name} ({exc.strerror})", field=where) from None
    return out


def write_outputs(out_dir: Path, campaign: Campaign, result: CampaignResult) -> dict[str, Any]:
    """The cycle documents in install order (``NN-ID.json``) and ``summary.json``; the summary.

    Files ``NN-*.json`` of an earlier run in the folder are replaced. The campaign's time is the sum of
    its cycles' durations (the robot's time, each cycle from park to park).
    """
    out_dir = Path(out_dir)
    for old in out_dir.glob("[0-9][0-9]-*.json"):
        old.unlink()
    for entry in result.units:
        src = entry.get("source")
        if entry.get("position") is None or not src or entry["status"] == "not_planned":
            entry["file"] = None
            continue
        suffix = ".json" if entry["status"] == "planned" else ".refused.json"
        name = f"{entry['position']:02d}-{entry['id']}{suffix}"
        shutil.copyfile(out_dir / src, out_dir / f".{name}.tmp")
        (out_dir / f".{name}.tmp").replace(out_dir / name)
        entry["file"] = name
    durations = [e["duration_s"] for e in result.units if e["status"] == "planned"]
    summary: dict[str, Any] = {
        "kind": "campaign",
        "campaign": {"name": campaign.name, "sha256": campaign_sha256(campaign)},
        "order_mode": campaign.order,
        "status": "succeeded" if result.succeeded else "failed",
        "message": result.message,
        "order": result.order,
        "units": result.units,
        "campaign_duration_s": float(sum(durations)) if result.succeeded else None,
        "planned_duration_s": float(sum(durations)),
        "cycles_planned": result.cycles_planned,
        "cycles_cached": result.cycles_cached,
        "wall_time_s": result.wall_time_s,
    }
    if result.search is not None:
        summary["search"] = result.search
    atomic_write(out_dir / "summary.json", json.dumps(summary, indent=1, allow_nan=False) + "\n")
    return summary
