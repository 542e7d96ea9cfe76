"""Campaigns: install a list of units one cycle at a time, in a cabin that fills up.

Every cycle is planned in the cabin as it stands after the installs before it: the units installed so far
are obstacles of the cycle's collision world (``"unit <id>"``, compared by clearance like the cabin, see
:mod:`planner.collision.obstacles`), added without rebuilding the cabin's mesh-derived caches. What a cycle
meets depends on the *set* of units installed before it, so a cycle is keyed by the hash of its composed
cycle document (:func:`cycle_key`: the unit, the set of installed units, the cabin with its mesh files'
content, the park posture, the options); a cycle with a known key is never planned again -- within a run
(``order: find`` asks the same state from several orders), across runs, and after a kill.

* ``order: given`` (:meth:`CampaignRun.given`): the cycles of the listed order are independent plans
  (cycle k's cabin holds units 0..k-1 whatever their plans did), so they run in parallel on the executor;
  the campaign stops at the first cycle refused and says what blocks it from the refusal's evidence, e.g.
  "unit B3, installed second, is 4.0 mm from the payload in the transit (10.0 mm required): install A1
  before B3".
* ``order: find`` (:meth:`CampaignRun.find`): the search of :mod:`planner.task.order` over install states,
  its batches planned in parallel on the executor, pruned by what each refusal names.

Cycles run on the sweep executors (:mod:`planner.sweep.run`: embedded warm workers or Ray), each as a task
whose runner is :func:`planner.task.campaign_task.cycle_outcome`. The output folder (see
:func:`write_outputs`)::

    OUT_DIR/cycles/results.jsonl      the journal: one row per planned cycle, keyed by its hash (resume)
    OUT_DIR/cycles/profiles/KEY.json  each cycle's document (profile or refusal), written by its process
    OUT_DIR/cycles/scenarios/KEY.json each composed cycle document (``cabinplan cycle`` re-runs it)
    OUT_DIR/NN-ID.json                the cycle documents in install order (NN from 01)
    OUT_DIR/NN-ID.refused.json        the first refused cycle of a given order (its refusal document)
    OUT_DIR/summary.json              order, per-unit status, durations, the campaign's time, evidence
"""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from planner.core.exceptions import InvalidInput
from planner.sweep.results import Journal, atomic_write
from planner.sweep.run import Executor, Job, drive
from planner.sweep.spec import Limits
from planner.task.campaign_schema import Campaign, CampaignUnit
from planner.task.evidence import Mention, mentions, nearest
from planner.task.order import FindResult, Query, Verdict, find_order

_LOG = logging.getLogger(__name__)

__all__ = [
    "CYCLE_RUNNER",
    "MONOTONICITY",
    "CampaignResult",
    "CampaignRun",
    "CycleJob",
    "UnitStatus",
    "blocking_message",
    "campaign_meshes",
    "campaign_sha256",
    "cycle_document",
    "cycle_key",
    "installed_entry",
    "ordinal",
    "write_outputs",
]

#: The executors' runner of one campaign cycle (:func:`planner.sweep.task.task_runner`).
CYCLE_RUNNER = "planner.task.campaign_task:cycle_outcome"
#: The assumption the order search prunes with (said in every summary of ``order: find``).
MONOTONICITY = (
    "an installed unit only takes free space away: a cycle refused with the units B installed stays "
    "refused whenever B is installed"
)
#: Refusal reasons that do not depend on the cabin state: the unit cannot be installed in any order.
STATE_INDEPENDENT = frozenset({"invalid_input", "invalid_mesh", "invalid_robot_description", "unknown_robot"})


# ------------------------------------------------------------------------------------------ composition


def installed_entry(unit: CampaignUnit) -> dict[str, Any]:
    """The unit as an installed unit of later cycles: its geometry at its bay pose (an ``installed`` entry).

    After release the unit stays where its cycle put it: the bay's pose (the insertion lands the unit on
    it, deflection compensated).
    """
    shape = unit.unit.model_dump(mode="json", include={"box", "mesh", "units"}, exclude_none=True)
    return {"id": unit.id, **shape, "pose": unit.bay.pose.model_dump(mode="json")}


def cycle_document(campaign: Campaign, unit_id: str, installed: Iterable[str]) -> dict[str, Any]:
    """The cycle document of ``unit_id`` installed after the campaign units ``installed`` (any order).

    The units installed before the campaign come first, as given, then the campaign's units installed
    before this one in their listed order (a set: equal states give equal documents, whatever the order
    they were installed in).
    """
    unit = campaign.unit(unit_id)
    before = set(installed)
    if unit_id in before:
        raise InvalidInput(f"units: {unit_id} cannot be installed twice", field="units")
    entries = [e.model_dump(mode="json", exclude_none=True) for e in campaign.installed]
    entries += [installed_entry(u) for u in campaign.units if u.id in before]
    doc: dict[str, Any] = {"name": f"{campaign.name}-{unit_id}", "robot": campaign.robot}
    if campaign.rail_length is not None:
        doc["rail_length"] = campaign.rail_length
    doc.update(
        cabin=campaign.cabin.model_dump(mode="json"),
        installed=entries,
        unit=unit.unit.model_dump(mode="json", exclude_none=True),
        dock=unit.dock.model_dump(mode="json"),
        bay=unit.bay.model_dump(mode="json"),
        retract=unit.retract_line().model_dump(mode="json"),
        park=campaign.park.model_dump(mode="json", exclude_none=True),
        dwell=(unit.dwell or campaign.dwell).model_dump(mode="json"),
        options=campaign.options.model_dump(mode="json"),
    )
    if campaign.gripper is not None:
        doc["gripper"] = campaign.gripper.model_dump(mode="json")
    return doc


def _mesh_digests(node: Any, base_dir: Path | None, out: dict[str, str]) -> None:
    """sha256 of every mesh file a document names (key ``mesh``), by name; reference cabins by their file."""
    if isinstance(node, dict):
        for key, value in node.items():
            if key == "mesh" and isinstance(value, str) and value not in out:
                out[value] = _file_digest(value, base_dir)
            else:
                _mesh_digests(value, base_dir, out)
    elif isinstance(node, list):
        for value in node:
            _mesh_digests(value, base_dir, out)


def _file_digest(name: str, base_dir: Path | None) -> str:
    from meshes import reference_cabin_path

    path = reference_cabin_path(name)
    if path is None:
        path = Path(name) if Path(name).is_absolute() or base_dir is None else base_dir / name
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:  # the cycle's own resolution reports it; the key still tells the name apart
        return "missing"


def cycle_key(document: dict[str, Any], base_dir: Path | None = None) -> str:
    """The cycle's feasibility key: sha256 of its canonical document (without its name) and mesh contents.

    Equal keys plan equal cycles: the same unit, dock and bay, the same installed units at the same poses,
    the same cabin (file content included), park posture and options.
    """
    meshes: dict[str, str] = {}
    _mesh_digests(document, base_dir, meshes)
    body = {k: v for k, v in document.items() if k != "name"}
    canonical = json.dumps({"cycle": body, "meshes": meshes}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class CycleJob:
    """One cycle of a campaign as the executors see it (:class:`planner.sweep.run.TaskKey`).

    Attributes:
        unit: The unit installed.
        installed: The campaign units installed before it.
        sha256: :func:`cycle_key` of its document.
        document: The composed cycle document.
    """

    unit: str
    installed: frozenset[str]
    sha256: str
    document: dict[str, Any] = field(repr=False, compare=False)

    @property
    def name(self) -> str:
        """The file name of its documents: the unit and the key's first 16 hex digits."""
        return f"{self.unit}-{self.sha256[:16]}"


# ------------------------------------------------------------------------------------------- evidence

_ORDINALS = (
    "first second third fourth fifth sixth seventh eighth ninth tenth eleventh twelfth thirteenth "
    "fourteenth fifteenth sixteenth"
).split()


def ordinal(k: int) -> str:
    """0 -> 'first', 1 -> 'second', ... (``k+1``-th past the sixteenth)."""
    return _ORDINALS[k] if 0 <= k < len(_ORDINALS) else f"{k + 1}th"


def _where(m: Mention) -> str:
    if not m.where:
        return ""
    text = m.where.replace("_", " ")
    if text.startswith(("at ", "on ", "in ", "along ", "near ", "during ")):
        return f" {text}"
    return f" in the {text}"


def blocking_message(unit: str, m: Mention, position: str, fixed: bool) -> str:
    """One line naming a blocker and what to do: "unit B3, installed second, is 4.0 mm from ...".

    Args:
        unit: The unit whose cycle was refused.
        m: The blocker's most telling mention.
        position: How it came to be installed (``"installed second"``, ``"installed before the campaign"``).
        fixed: It was installed before the campaign (no order of this campaign moves it).
    """
    body = "the payload" if m.body in (None, "payload") else m.body
    if m.distance_m is None:
        figure = f"is named by the refusal{_where(m)}"
    elif m.distance_m <= 0.0:
        figure = f"is in contact with {body}{_where(m)}"
    else:
        figure = f"is {1e3 * m.distance_m:.1f} mm from {body}{_where(m)}"
    if m.required_m is not None:
        figure += f" ({1e3 * m.required_m:.1f} mm required)"
    advice = f"no order of this campaign installs {unit}" if fixed else f"install {unit} before {m.unit}"
    return f"unit {m.unit}, {position}, {figure}: {advice}"


def _row_evidence(row: dict[str, Any]) -> Any:
    text = row.get("evidence")
    if not isinstance(text, str):
        return None
    try:
        return json.loads(text)
    except json.JSONDecodeError:  # cut at the table's length: the document has it whole
        return None


# ------------------------------------------------------------------------------------------- results


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
        self.planned = 0
        self.cached = 0
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
        limits: Limits = self.campaign.limits
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
        for k, job in enumerate(jobs):
            if self.journal.done(job.sha256):
                self.cached += 1
                self.status[job.unit].cycles_cached += 1
                row = self.journal.rows[job.sha256]
                if stop_at_refusal and row.get("status") != "succeeded":
                    break
                continue
            self._write_input(job)
            pending.append(Job(job, self._task(job), self._hard_limit_s(job)))
            del k
        index = {job.sha256: k for k, job in enumerate(jobs)}
        stop = [len(jobs)]

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
                stop[0] = min(stop[0], k)
                for j in [j for j in pending if index[j.plan.sha256] > k]:
                    pending.remove(j)

        def running_changed(n: int) -> None:
            for u in self.status.values():
                if u.status == "planning":
                    u.status = "waiting"
            for j in self.executor_jobs(pending, jobs):
                self.status[j].status = "planning"
            self._progress(self.status)

        if pending:
            if self.executor is None:
                raise RuntimeError("campaign: cycles to plan but no executor set")
            drive(pending, self.executor, finished, running_changed=running_changed, poll_s=self.poll_s)
        return [self.journal.rows.get(job.sha256, {}) for job in jobs]

    def executor_jobs(self, pending: deque[Job[CycleJob]], jobs: Sequence[CycleJob]) -> list[str]:
        """Units whose cycle was submitted and has no row yet (running now)."""
        waiting = {j.plan.sha256 for j in pending}
        return [j.unit for j in jobs if j.sha256 not in waiting and not self.journal.done(j.sha256)]

    def _mark(self, unit: str, status: str, row: dict[str, Any] | None = None) -> None:
        st = self.status[unit]
        st.status = status
        if row is not None:
            st.message = str(row.get("message") or "")
        self._progress(self.status)

    # ------------------------------------------------------------- verdicts
    def verdict(self, job: CycleJob, row: dict[str, Any]) -> tuple[Verdict, dict[str, Mention]]:
        """The feasibility verdict of a planned cycle, and the installed units its refusal names."""
        if row.get("status") == "succeeded":
            return Verdict(True, message=str(row.get("message") or "")), {}
        found = nearest(mentions(_row_evidence(row), row.get("message"), set(job.installed) | self._initial))
        blockers = frozenset(u for u in found if u in job.installed)
        fixed_units = [u for u in found if u in self._initial]
        fixed = (not blockers and bool(fixed_units)) or (
            row.get("reason") in STATE_INDEPENDENT and not blockers
        )
        reason = str(row.get("reason") or "failed")
        text = f"{reason}: {row.get('message') or ''}".strip()
        return Verdict(False, blockers, fixed, reason, text), found

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
    from meshes import reference_cabin_path

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


def campaign_sha256(campaign: Campaign) -> str:
    """SHA-256 of the campaign's canonical JSON."""
    text = json.dumps(campaign.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


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
