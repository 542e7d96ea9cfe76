"""A campaign's cycles: each composed in the cabin as it stands after the installs before it, and keyed.

Every cycle of a campaign is an ordinary cycle document (:mod:`planner.task.schema`) whose installed units
are those installed before the campaign plus the campaign's units installed before it, each at its bay
pose: obstacles of the cycle's collision world (``"unit <id>"``, compared by clearance like the cabin,
:mod:`planner.collision.obstacles`), added without rebuilding the cabin's mesh-derived caches. What a cycle
meets depends on the *set* of units installed before it, so a cycle is keyed by the hash of its document
(:func:`cycle_key`: the unit, the set of installed units, the cabin with its mesh files' content, the park
posture, the options): a cycle with a known key is never planned again.

A refused cycle's evidence names what blocks it (:mod:`planner.task.evidence`); :func:`verdict_of` turns a
planned cycle's outcome into the order search's :class:`~planner.task.order.Verdict` and
:func:`blocking_message` into one line a line engineer acts on: "unit B3, installed second, is 4.0 mm
from the payload in the transit (10.0 mm required): install A1 before B3".

Pure functions over the validated campaign and plain outcome data; running the cycles is
:mod:`planner.campaign.run`.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from planner.core.exceptions import InvalidInput
from planner.task.campaign_schema import Campaign, CampaignUnit
from planner.task.evidence import Mention, mentions, nearest
from planner.task.order import Verdict

if TYPE_CHECKING:
    from planner.scenario.resolve import MeshResolver

__all__ = [
    "MONOTONICITY",
    "STATE_INDEPENDENT",
    "CycleJob",
    "blocking_message",
    "campaign_sha256",
    "check_campaign",
    "cycle_document",
    "cycle_key",
    "installed_entry",
    "ordinal",
    "verdict_of",
]

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
    from planner.meshes import reference_cabin_path

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
    """`` at the goal of the transit leg`` / `` in the transit leg`` / ``""``."""
    leg = m.leg.replace("_", " ") if m.leg else None
    if m.where:
        return f" {m.where} of the {leg} leg" if leg else f" {m.where}"
    return f" in the {leg} leg" if leg else ""


def blocking_message(unit: str, m: Mention, position: str, fixed: bool) -> str:
    """One line naming a blocker and what to do: "unit B3, installed second, is 4.0 mm from ...".

    Args:
        unit: The unit whose cycle was refused.
        m: The blocker's most telling mention.
        position: How it came to be installed (``"installed second"``, ``"installed before the campaign"``).
        fixed: It was installed before the campaign (no order of this campaign moves it).
    """
    body = f"the {m.body or 'payload'}"
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


def verdict_of(
    row: dict[str, Any], installed: frozenset[str], initial: frozenset[str], details: Any = None
) -> tuple[Verdict, dict[str, Mention]]:
    """The order search's verdict of a planned cycle, and every installed unit its refusal names.

    Args:
        row: The cycle's outcome row (``status``, ``reason``, ``message``, ``evidence``: the refusal's
            details as JSON text).
        installed: The campaign units installed before the cycle.
        initial: The units installed before the campaign (no order of the campaign moves them).
        details: The refusal's whole ``details`` (its document), when at hand: the row's evidence is cut
            at the journal's length.

    Returns:
        The verdict (blockers: the campaign units named; ``fixed`` when only bodies that are there in every
        state are named, or the refusal does not depend on the cabin state) and, per named unit, its most
        telling mention.
    """
    if row.get("status") == "succeeded":
        return Verdict(True, message=str(row.get("message") or "")), {}
    evidence = details if details is not None else _row_evidence(row)
    found = nearest(mentions(evidence, row.get("message"), set(installed) | set(initial)))
    blockers = frozenset(u for u in found if u in installed)
    fixed = not blockers and (any(u in initial for u in found) or row.get("reason") in STATE_INDEPENDENT)
    reason = str(row.get("reason") or "failed")
    text = f"{reason}: {row.get('message') or ''}".strip()
    return Verdict(False, blockers, fixed, reason, text), found


def campaign_sha256(campaign: Campaign) -> str:
    """SHA-256 of the campaign's canonical JSON."""
    text = json.dumps(campaign.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


#: Cycle fields a campaign gives for every cycle (their errors are the campaign's, not a unit's).
_CAMPAIGN_FIELDS = frozenset(
    {"robot", "rail_length", "cabin", "installed", "park", "dwell", "gripper", "options"}
)


def check_campaign(
    campaign: Campaign, base_dir: Path | None = None, mesh_resolver: MeshResolver | None = None
) -> None:
    """Refuse a campaign no order can install for a reason of its input, naming the fields and the units.

    * two units (the campaign's, or one installed before it) overlapping at their installed poses: one
      resolution of a cycle with every other unit installed (:func:`planner.task.resolve.resolve_cycle`
      checks every installed pair and the unit's bay against them);
    * each unit's own cycle in the cabin as the campaign finds it: its robot, cabin and meshes, its dock
      clear of its fixture and of the units installed before the campaign, its bay free of them.

    What depends on the order (a dock that an installed unit of the campaign overlaps) is the cycles' to
    refuse in the states where it holds.

    ``mesh_resolver``: how mesh names resolve (the service's store of uploaded meshes), as for a cycle.

    Raises:
        InvalidInput: ``units``/``units[k]...`` with the cycle's reason (``details['units']`` names both
            units of an overlap).
    """
    from planner.task.resolve import resolve_cycle
    from planner.task.schema import cycle_from_dict

    ids = campaign.ids
    index = {u: k for k, u in enumerate(ids)}
    if len(ids) > 1:
        try:
            resolve_cycle(cycle_from_dict(cycle_document(campaign, ids[0], ids[1:])), base_dir, mesh_resolver)
        except InvalidInput as exc:
            field_name = str(exc.details.get("field", ""))
            named = [str(n) for n in exc.details.get("units", [])]
            if field_name in ("installed", "bay.pose") and len(named) == 2:
                where = [f"units[{index[n[5:]]}]" if n[5:] in index else "installed" for n in named]
                raise InvalidInput(
                    f"units: {named[0]} ({where[0]}) and {named[1]} ({where[1]}) overlap at their installed "
                    "poses: no order installs both",
                    field="units",
                    units=named,
                ) from None
    for k, unit_id in enumerate(ids):
        try:
            resolve_cycle(cycle_from_dict(cycle_document(campaign, unit_id, ())), base_dir, mesh_resolver)
        except InvalidInput as exc:
            field_name = str(exc.details.get("field", "cycle"))
            prefix = (
                ""
                if field_name in ("robot", "cabin", "cabin.mesh", "park", "rail_length")
                else f"units[{k}]."
            )
            raise InvalidInput(
                f"{prefix}{exc.message} (unit {unit_id})",
                **{**exc.details, "field": f"{prefix}{field_name}", "unit": unit_id},
            ) from None
