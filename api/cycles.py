"""The child side of cycle and campaign jobs, and the files made from their results on request.

Both kinds run in a job process like plans (:mod:`api.worker`), with the planner's own use cases:

* :func:`cycle_job`: one assembly cycle (:func:`planner.task.cycle.plan_cycle`), its profile document or its
  refusal (:mod:`planner.documents.cycle`); the progress is the leg being planned.
* :func:`campaign_job`: a campaign (:class:`planner.campaign.run.CampaignRun`) with its cycles planned one
  after the other in this process (:class:`~planner.sweep.run.InlineExecutor`: the service's worker count
  is its parallelism), in a private folder that holds the campaign's cycle journal. Each finished cycle
  (its journal row and its document) is sent to the server as a *kept* file of the job (stored in the
  database, :class:`api.db.JobFile`), and a relaunched job (its server killed, the lease lapsed) starts
  from the kept cycles: nothing finished is planned again. The progress carries every unit's status
  (``units``: waiting, planning, planned, refused, not_planned) as it changes.

The campaign's result document is the summary (:func:`planner.campaign.run.write_outputs`: order, units,
message, durations, search) with ``"cycles"``: the cycle documents in install order (a refused cycle's
refusal document last, for a given order).

Files made on request (server side, :mod:`api.jobkinds`): a cycle's ``profile.csv`` (the drive profile
with each sample's leg) and ``plot.png`` (:func:`planner.documents.cycle.cycle_png`'s plot); a campaign's
``profile.csv`` (every planned cycle one after the other, with the unit and the leg of each sample),
``units.csv`` (one row per unit) and ``plot.png`` (each unit's cycle as a bar of its legs on the
campaign's timeline).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from api.compact import pack_value, unpack_document
from api.jobtypes import KEEP_PREFIX, FileSource
from api.worker import failed_outcome, succeeded_outcome

_LOG = logging.getLogger(__name__)


def cycle_mesh_resolver(meshes: dict[str, str]) -> Any:
    """Mesh names of a cycle or campaign job -> the tenant's stored files (names checked at submission)."""
    from api.store import scenario_mesh_resolver

    return scenario_mesh_resolver(meshes)


# ------------------------------------------------------------------------------------------------ cycles
def cycle_job(job: dict[str, Any], progress: Any) -> dict[str, Any]:
    """Plan one cycle job; the outcome ``{"status", "reason", "message", "document", "provenance"}``.

    Args:
        job: ``{"id", "scenario" (the cycle document as submitted), "meshes" ({id: path}), "empty_dir"}``.
        progress: Called with ``(leg, fraction of the cycle)`` as the legs start.
    """
    from planner.core.exceptions import PlannerError
    from planner.documents.cycle import cycle_document, cycle_refusal_document
    from planner.task.cycle import plan_cycle
    from planner.task.resolve import ResolvedCycle, resolve_cycle
    from planner.task.schema import cycle_from_dict

    cyc: ResolvedCycle | None = None
    try:
        spec = cycle_from_dict(job["scenario"], source="cycle")
        cyc = resolve_cycle(
            spec, base_dir=Path(job["empty_dir"]), mesh_resolver=cycle_mesh_resolver(job["meshes"])
        )
        result = plan_cycle(cyc, progress)
    except PlannerError as exc:
        return failed_outcome(exc, cycle_refusal_document(exc, cyc, name=job["scenario"].get("name")))
    message = (
        f"{spec.name}: {result.profile.duration_s:.3f} s, {len(result.profile.t)} samples, "
        f"min clearance {1e3 * result.gate.min_clearance_m:.1f} mm"
    )
    return succeeded_outcome(cycle_document(cyc, result), message)


# --------------------------------------------------------------------------------------------- campaigns
def _restore(out_dir: Path, kept: dict[str, bytes]) -> int:
    """Write the kept cycles of an earlier attempt into the journal folder; how many."""
    cycles = out_dir / "cycles"
    (cycles / "profiles").mkdir(parents=True, exist_ok=True)
    lines = []
    for data in kept.values():
        item = unpack_document(data)
        row, document = item["row"], item["document"]
        if row.get("profile_file") and document is not None:
            (out_dir / row["profile_file"]).write_text(json.dumps(document), encoding="utf-8")
        lines.append(json.dumps(row, separators=(",", ":")) + "\n")
    if lines:
        with (cycles / "results.jsonl").open("a", encoding="utf-8") as fh:
            fh.writelines(lines)
    return len(lines)


def unit_rows(status: dict[str, Any]) -> list[dict[str, Any]]:
    """Every unit's status as the job document shows it (``units``)."""
    return [
        {
            "id": s.unit,
            "status": s.status,
            "cycles_planned": s.cycles_planned,
            "cycles_cached": s.cycles_cached,
            "message": s.message,
        }
        for s in status.values()
    ]


def campaign_job(job: dict[str, Any], progress: Any) -> dict[str, Any]:
    """Run one campaign job (see the module docstring); the outcome, with the result document.

    Args:
        job: ``{"id", "scenario" (the campaign as submitted), "meshes", "empty_dir", "kept" ({name: packed
            {"row", "document"}} of an earlier attempt)}``.
        progress: Called with ``(stage, fraction, {"units": [...]})``; ``progress.keep(name, data)`` hands a
            finished cycle to the server.
    """
    from planner.campaign.run import CampaignRun, write_outputs
    from planner.core.exceptions import PlannerError
    from planner.sweep.run import InlineExecutor
    from planner.task.campaign_schema import campaign_from_dict

    campaign = campaign_from_dict(job["scenario"], source="campaign")
    out_dir = Path(tempfile.mkdtemp(prefix=f"campaign-{job['id'][:12]}-"))
    try:
        restored = _restore(out_dir, dict(job.get("kept") or {}))
        sent: set[str] = set()
        n = len(campaign.units)
        state: dict[str, Any] = {"run": None}

        def on_status(status: dict[str, Any]) -> None:
            run = state["run"]
            if run is not None:
                for key, row in list(run.journal.rows.items()):
                    if key in sent:
                        continue
                    sent.add(key)
                    doc = None
                    if row.get("profile_file"):
                        doc = json.loads((out_dir / row["profile_file"]).read_text(encoding="utf-8"))
                    keep = getattr(progress, "keep", None)
                    if keep is not None:
                        keep(f"{KEEP_PREFIX}{key[:32]}", pack_value({"row": row, "document": doc}))
            done = sum(s.status in ("planned", "refused", "not_planned") for s in status.values())
            planning = [s.unit for s in status.values() if s.status == "planning"]
            stage = f"unit {planning[0]}" if planning else "campaign"
            progress(stage, min(done / n, 0.99), {"units": unit_rows(status)})

        run = CampaignRun(
            campaign,
            out_dir,
            InlineExecutor(job["meshes"]),
            base_dir=Path(job["empty_dir"]),
            progress=on_status,
            poll_s=0.05,
        )
        state["run"] = run
        for key in run.journal.rows:
            sent.add(key)
        if restored:
            _LOG.info("campaign job %s: %d cycles kept from an earlier attempt", job["id"], restored)
        t0 = time.perf_counter()
        result = run.given() if campaign.order == "given" else run.find()
        summary = write_outputs(out_dir, campaign, result)
        on_status(run.status)
        cycles = []
        for entry in summary["units"]:
            if entry.get("file"):
                cycles.append(json.loads((out_dir / entry["file"]).read_text(encoding="utf-8")))
        document = {**summary, "cycles": cycles}
        refused = next((u for u in summary["units"] if u["status"] == "refused"), None)
        reason = None
        if not result.succeeded:
            found = refused.get("reason") if refused is not None else None
            reason = "no_order_found" if campaign.order == "find" else str(found or "cycle_refused")
        progress("done", 1.0, {"units": unit_rows(run.status)})
        _LOG.info("campaign job %s: %s (%.1f s)", job["id"], result.message, time.perf_counter() - t0)
        return {
            "status": "succeeded" if result.succeeded else "failed",
            "reason": reason,
            "message": result.message,
            "document": document,
            "provenance": {"campaign_sha256": summary["campaign"]["sha256"]},
        }
    except PlannerError as exc:
        doc = {"kind": "campaign", "status": "failed", **exc.to_dict()}
        return {"status": "failed", "reason": exc.reason, "message": exc.message, "document": doc}
    finally:
        shutil.rmtree(out_dir, ignore_errors=True)


# ------------------------------------------------------------------------------- files made on request
def _resolved_cycle(data: dict[str, Any], source: FileSource) -> Any:
    from planner.task.resolve import resolve_cycle
    from planner.task.schema import cycle_from_dict

    return resolve_cycle(
        cycle_from_dict(data, source="cycle"),
        base_dir=Path(source.empty_dir),
        mesh_resolver=cycle_mesh_resolver(source.meshes),
    )


def _profile_rows(
    doc: dict[str, Any], t_offset_s: float, unit: str | None
) -> tuple[list[str], list[list[str]]]:
    """Header and rows of one cycle document's profile: t, [unit,] leg, then the drive columns."""
    from planner.robots import load_robot
    from planner.timing.profile import DriveProfile

    robot = load_robot(str(doc["robot"]))
    text = DriveProfile.from_dict(doc, robot).to_csv().splitlines()
    legs = [str(x["name"]) for x in doc["legs"]]
    head = text[0].split(",")
    header = ["t_s", *(["unit"] if unit is not None else []), "leg", *head[1:]]
    rows = []
    for k, line in enumerate(text[1:]):
        cells = line.split(",")
        t = float(doc["t"][k]) + t_offset_s
        rows.append([f"{t:.9g}", *([unit] if unit is not None else []), legs[int(doc["leg"][k])], *cells[1:]])
    return header, rows


def _csv(header: list[str], rows: list[list[Any]]) -> bytes:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue().encode()


def cycle_profile_csv(source: FileSource) -> bytes:
    """A cycle's drive profile as CSV: ``t_s``, ``leg``, then position, velocity, ... of each drive."""
    header, rows = _profile_rows(source.document, 0.0, None)
    return _csv(header, rows)


def cycle_plot_png(source: FileSource) -> bytes:
    """The cycle's drive profile against its limits, the legs and the events in the title."""
    from planner.documents.plot import profile_png
    from planner.robots import load_robot
    from planner.robots.cabin8 import Cabin8
    from planner.timing.profile import DriveProfile

    doc = source.document
    robot = load_robot(str(doc["robot"]))
    if not isinstance(robot, Cabin8):  # cycles are cabin8 cycles
        raise ValueError(f"no cycle plot for robot {robot.name!r}")
    profile = DriveProfile.from_dict(doc, robot)

    legs = " | ".join(f"{x['name']} {x['t_start_s']:.1f}" for x in doc["legs"])
    events = ", ".join(
        f"{e['kind']} {e['unit']} {e['t_s']:.2f} s ({1e3 * e['springback_m']:.2f} mm)" for e in doc["events"]
    )
    title = f"{doc['cycle']['name']}: {profile.duration_s:.2f} s\nlegs from [s]: {legs}\n{events}"
    return profile_png(profile, robot, title=title)


def campaign_profile_csv(source: FileSource) -> bytes:
    """Every planned cycle of a campaign in turn: ``t_s`` (campaign time), ``unit``, ``leg``, the drives."""
    header: list[str] = []
    rows: list[list[str]] = []
    offset = 0.0
    for doc in source.document.get("cycles", []):
        if doc.get("status") != "succeeded":
            continue
        unit = next(e["unit"] for e in doc["events"])
        header, part = _profile_rows(doc, offset, str(unit))
        rows += part
        offset += float(doc["t"][-1])
    if not header:
        raise ValueError("the campaign planned no cycle")
    return _csv(header, rows)


#: Columns of a campaign's ``units.csv``.
UNIT_COLUMNS = (
    "position",
    "id",
    "status",
    "duration_s",
    "min_clearance_m",
    "planning_time_s",
    "installed_before",
    "reason",
    "message",
)


def campaign_units_csv(source: FileSource) -> bytes:
    """One row per unit of a campaign: install position, status, cycle duration, clearance, message."""
    rows = []
    for u in source.document.get("units", []):
        cells = []
        for c in UNIT_COLUMNS:
            v = u.get(c)
            cells.append(" ".join(v) if isinstance(v, list) else ("" if v is None else v))
        rows.append(cells)
    return _csv(list(UNIT_COLUMNS), rows)


def campaign_plot_png(source: FileSource) -> bytes:
    """Each planned unit's cycle as a horizontal bar of its legs on the campaign's timeline (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    doc = source.document
    cycles = [c for c in doc.get("cycles", []) if c.get("status") == "succeeded"]
    names = [leg["name"] for leg in cycles[0]["legs"]] if cycles else []
    colours = {n: plt.get_cmap("tab10")(k % 10) for k, n in enumerate(names)}
    fig, ax = plt.subplots(figsize=(10, 1.8 + 0.5 * max(1, len(doc.get("units", [])))))
    offset = 0.0
    labels = []
    for row, u in enumerate(doc.get("units", [])):
        labels.append(f"{u['id']} ({u['status']})")
        c = next((c for c in cycles if any(e["unit"] == u["id"] for e in c["events"])), None)
        if c is None:
            continue
        for leg in c["legs"]:
            ax.barh(
                row,
                leg["t_end_s"] - leg["t_start_s"],
                left=offset + leg["t_start_s"],
                color=colours[leg["name"]],
                edgecolor="none",
            )
        for e in c["events"]:
            ax.plot(offset + e["t_s"], row, "kv" if e["kind"] == "attach" else "k^", ms=6)
        offset += float(c["t"][-1])
    ax.set_yticks(range(len(labels)), labels)
    ax.invert_yaxis()
    ax.set_xlabel("campaign time [s]")
    handles = [plt.Rectangle((0, 0), 1, 1, color=colours[n]) for n in names]
    if handles:
        fig.legend(handles, names, ncol=9, fontsize=7, loc="lower center")
    total = doc.get("campaign_duration_s") or doc.get("planned_duration_s") or 0.0
    ax.set_title(
        f"{doc['campaign']['name']}: {doc['status']}, {total:.1f} s; {doc['message']}"[:160], fontsize=9
    )
    fig.tight_layout(rect=(0.0, 0.08, 1.0, 1.0))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


__all__ = [
    "campaign_job",
    "campaign_plot_png",
    "campaign_profile_csv",
    "campaign_units_csv",
    "cycle_job",
    "cycle_mesh_resolver",
    "cycle_plot_png",
    "cycle_profile_csv",
    "unit_rows",
]
