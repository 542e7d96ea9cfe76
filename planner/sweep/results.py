"""Result rows of a sweep: one per plan, the resumable journal, and the CSV and Parquet tables.

Layout of an output folder::

    OUT_DIR/results.jsonl     journal: one JSON row per finished plan, appended and fsynced as it finishes
    OUT_DIR/results.csv       the table (rewritten from the journal at the end of a run)
    OUT_DIR/results.parquet   the same table, typed (pyarrow)
    OUT_DIR/scenarios/NAME.json   each plan as an ordinary scenario file (``cabinplan plan`` re-runs it)
    OUT_DIR/profiles/NAME.json    the drive profile, or the refusal document with its evidence
    OUT_DIR/*.png             summary plots (:mod:`planner.sweep.plots`)

The journal is keyed by the scenario hash: a rerun skips every plan whose hash has a row, and a row is
written once (a plan finished twice, e.g. a retried task, keeps its first row). A row is appended only
after its profile file is in place, so a row never points at a missing file.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from planner.sweep.expand import SweepPlan

_LOG = logging.getLogger(__name__)

JOURNAL = "results.jsonl"
CSV_FILE = "results.csv"
PARQUET_FILE = "results.parquet"

#: The columns of the table in order, with their type (``str``, ``int`` or ``float``; every one nullable).
COLUMNS: tuple[tuple[str, str], ...] = (
    ("plan", "int"),
    ("name", "str"),
    ("scenario_sha256", "str"),
    ("scenario_file", "str"),
    ("bay", "str"),
    ("goal_x_m", "float"),
    ("goal_y_m", "float"),
    ("goal_z_m", "float"),
    ("start", "str"),
    ("grasp", "str"),
    ("payload_mass_kg", "float"),
    ("payload_box_m", "str"),
    ("clearance_m", "float"),
    ("seed", "int"),
    ("time_limit_s", "float"),
    ("status", "str"),
    ("reason", "str"),
    ("message", "str"),
    ("evidence", "str"),
    ("duration_s", "float"),
    ("lower_bound_ratio", "float"),
    ("min_clearance_m", "float"),
    ("min_clearance_bound_m", "float"),
    ("peak_force_ratio", "float"),
    ("planning_time_s", "float"),
    ("wall_time_s", "float"),
    ("attempts", "int"),
    ("profile_file", "str"),
)
COLUMN_NAMES = tuple(name for name, _ in COLUMNS)

#: Columns that depend on the machine (times, files), not on the plan: left out when comparing runs.
MACHINE_COLUMNS = frozenset({"planning_time_s", "wall_time_s", "attempts", "scenario_file", "profile_file"})


def plan_columns(plan: SweepPlan) -> dict[str, Any]:
    """The columns that describe what a plan varies (from its scenario and axis labels)."""
    s = plan.scenario
    goal = s.goal.pose.position if s.goal.pose is not None else (None, None, None)
    payload = s.payload
    return {
        "plan": plan.index,
        "name": s.name,
        "scenario_sha256": plan.sha256,
        "scenario_file": f"scenarios/{s.name}.json",
        "bay": plan.labels.get("bay"),
        "goal_x_m": goal[0],
        "goal_y_m": goal[1],
        "goal_z_m": goal[2],
        "start": plan.labels.get("start"),
        "grasp": plan.labels.get("grasp"),
        "payload_mass_kg": payload.mass if payload is not None else None,
        "payload_box_m": json.dumps(list(payload.box)) if payload is not None and payload.box else None,
        "clearance_m": s.options.clearance_m,
        "seed": s.options.seed,
        "time_limit_s": s.options.time_limit_s,
    }


def make_row(plan: SweepPlan, outcome: dict[str, Any], wall_time_s: float, attempts: int) -> dict[str, Any]:
    """The result row of a finished plan (see :data:`COLUMNS`); ``outcome`` as from the task."""
    row = plan_columns(plan)
    for key in (
        "status",
        "reason",
        "message",
        "evidence",
        "duration_s",
        "lower_bound_ratio",
        "min_clearance_m",
        "min_clearance_bound_m",
        "peak_force_ratio",
        "planning_time_s",
    ):
        row[key] = outcome.get(key)
    row["wall_time_s"] = wall_time_s
    row["attempts"] = attempts
    written = outcome.get("document") or outcome.get("profile_written")
    row["profile_file"] = f"profiles/{plan.name}.json" if written else None
    return {name: row.get(name) for name in COLUMN_NAMES}


def outcome_from_document(
    status: str, reason: str | None, message: str | None, document: str | None
) -> dict[str, Any]:
    """A plan outcome (as :func:`planner.sweep.task.plan_outcome` gives) from a stored result document.

    The HTTP service keeps each plan's profile or refusal document (:mod:`planner.documents.output`); the
    table columns are read from it: ``report.duration_ratio``, ``min_clearance_m`` (and the gate's
    ``min_clearance_bound_m``), the gate's peak effort
    ratio and ``report.planning_time_s`` of a profile, ``details`` (the evidence) of a refusal.
    """
    from planner.sweep.task import MAX_EVIDENCE_CHARS

    out: dict[str, Any] = {"status": status, "reason": reason, "message": message, "document": document}
    doc = json.loads(document) if document else None
    if not isinstance(doc, dict):
        return out
    if status == "succeeded":
        report = doc.get("report") or {}
        out.update(
            duration_s=doc.get("duration_s"),
            lower_bound_ratio=report.get("duration_ratio"),
            min_clearance_m=doc.get("min_clearance_m"),
            min_clearance_bound_m=(report.get("gate") or {}).get("min_clearance_bound_m"),
            peak_force_ratio=((report.get("gate") or {}).get("peak_ratios") or {}).get("effort"),
            planning_time_s=report.get("planning_time_s"),
        )
    elif doc.get("details") is not None:
        evidence = json.dumps(doc["details"], separators=(",", ":"))
        out["evidence"] = (
            evidence if len(evidence) <= MAX_EVIDENCE_CHARS else evidence[: MAX_EVIDENCE_CHARS - 1] + "…"
        )
    return out


def atomic_write(path: Path, text: str | bytes) -> None:
    """Write the file through a temporary one, fsynced, then renamed over it (never a half file)."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as fh:
        fh.write(text.encode("utf-8") if isinstance(text, str) else text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


class Journal:
    """The append-only, fsynced journal of result rows, keyed by scenario hash.

    Args:
        out_dir: The sweep's output folder (created).
    """

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = Path(out_dir)
        for sub in ("", "scenarios", "profiles"):
            (self.out_dir / sub).mkdir(parents=True, exist_ok=True)
        self.path = self.out_dir / JOURNAL
        self.rows: dict[str, dict[str, Any]] = {}
        self._read()

    def _read(self) -> None:
        if not self.path.exists():
            return
        raw = self.path.read_bytes()
        if raw and not raw.endswith(b"\n"):  # a row cut short by a kill: dropped, so appends stay whole
            _LOG.warning("%s: incomplete last row dropped (its plan runs again)", self.path)
            with self.path.open("r+b") as fh:
                fh.truncate(raw.rfind(b"\n") + 1)
        with self.path.open("r", encoding="utf-8") as fh:
            for k, line in enumerate(fh):
                try:
                    row = json.loads(line)
                except json.JSONDecodeError:  # a line cut short by a kill: that plan runs again
                    _LOG.warning("%s:%d: incomplete row ignored", self.path, k + 1)
                    continue
                if isinstance(row, dict) and isinstance(row.get("scenario_sha256"), str):
                    self.rows.setdefault(row["scenario_sha256"], row)

    def done(self, sha256: str) -> bool:
        """A row of this scenario hash is recorded."""
        return sha256 in self.rows

    def profile_path(self, plan: SweepPlan) -> Path:
        """Where the plan's profile (or refusal document) goes: ``profiles/NAME.json``."""
        return self.out_dir / "profiles" / f"{plan.name}.json"

    def write_scenario(self, plan: SweepPlan) -> None:
        """The plan as an ordinary scenario file (``scenarios/NAME.json``)."""
        atomic_write(
            self.out_dir / "scenarios" / f"{plan.name}.json",
            json.dumps(plan.scenario.model_dump(mode="json"), indent=1) + "\n",
        )

    def record(self, plan: SweepPlan, row: dict[str, Any], document: str | None) -> bool:
        """Write the profile (or refusal) file, then append the row; False if the plan has a row already.

        ``document`` is ``None`` when there is none or the plan's process wrote it to
        :meth:`profile_path` itself (before it reported the outcome, so the row still follows the file).
        """
        if plan.sha256 in self.rows:
            _LOG.info("plan %s finished again; its first row is kept", plan.name)
            return False
        if document is not None:
            atomic_write(self.profile_path(plan), document + "\n")
        line = json.dumps(row, allow_nan=False, separators=(",", ":")) + "\n"
        with self.path.open("a", encoding="utf-8") as fh:
            fh.write(line)
            fh.flush()
            os.fsync(fh.fileno())
        self.rows[plan.sha256] = row
        return True

    def table(self, plans: Iterable[SweepPlan]) -> list[dict[str, Any]]:
        """Rows of these plans in plan order (current plan index); plans without a row are left out."""
        out = []
        for plan in plans:
            row = self.rows.get(plan.sha256)
            if row is not None:
                out.append({**{n: row.get(n) for n in COLUMN_NAMES}, "plan": plan.index})
        return out


def csv_text(rows: list[dict[str, Any]]) -> str:
    """The rows as CSV (header of :data:`COLUMN_NAMES`; empty cells for nulls)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(COLUMN_NAMES), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if v is None else v) for k, v in row.items()})
    return buf.getvalue()


def parquet_bytes(rows: list[dict[str, Any]]) -> bytes:
    """The rows as a Parquet file with the typed schema of :data:`COLUMNS`."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    types = {"str": pa.string(), "int": pa.int64(), "float": pa.float64()}
    schema = pa.schema([pa.field(name, types[kind], nullable=True) for name, kind in COLUMNS])
    table = pa.Table.from_pylist(rows, schema=schema)
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink)
    return bytes(sink.getvalue().to_pybytes())


def write_tables(out_dir: Path, rows: list[dict[str, Any]]) -> None:
    """``results.csv`` and ``results.parquet`` of the rows (atomic replace)."""
    atomic_write(Path(out_dir) / CSV_FILE, csv_text(rows))
    atomic_write(Path(out_dir) / PARQUET_FILE, parquet_bytes(rows))


def read_parquet(path: Path) -> list[dict[str, Any]]:
    """Rows of a results Parquet file (tests, notebooks)."""
    import pyarrow.parquet as pq

    return list(pq.read_table(path).to_pylist())


__all__ = [
    "COLUMNS",
    "COLUMN_NAMES",
    "CSV_FILE",
    "JOURNAL",
    "MACHINE_COLUMNS",
    "PARQUET_FILE",
    "Journal",
    "atomic_write",
    "csv_text",
    "make_row",
    "outcome_from_document",
    "parquet_bytes",
    "plan_columns",
    "read_parquet",
    "write_tables",
]
