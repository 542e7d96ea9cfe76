"""The independent re-check of a cycle profile document.

the one use case behind ``cabinplan check`` on a cycle (and, later, the service's validation route).

The gate trusts nothing the planner computed: each leg's world, load and line are rebuilt from the cycle
(:mod:`planner.task.legs`), the samples and the legs' ranges are read from the document, and
:func:`planner.gate.cycle.validate_cycle` runs on them.
"""

from __future__ import annotations

from typing import Any

from planner.core.exceptions import InvalidInput
from planner.gate.checks import GateReport
from planner.gate.cycle import validate_cycle
from planner.task.cycle import LegTiming, cycle_requirements
from planner.task.legs import LEG_NAMES, leg
from planner.task.resolve import ResolvedCycle
from planner.timing.profile import DriveProfile


def check_cycle(cyc: ResolvedCycle, document: dict[str, Any]) -> GateReport:
    """Run the whole-cycle gate on a cycle profile document (as written by ``cabinplan cycle``).

    Raises:
        InvalidInput: the document is a refusal, not a cycle profile, of another cycle, or its legs are not
            the cycle's (the field named).
    """
    if not isinstance(document, dict) or document.get("status", "succeeded") != "succeeded":
        raise InvalidInput(
            "profile: not a drive profile (a refusal document or not a JSON object)", field="profile.status"
        )
    if document.get("kind") != "cycle":
        raise InvalidInput(
            "profile.kind: not a cycle profile (expected kind 'cycle'; a plan's profile is checked "
            "against its scenario)",
            field="profile.kind",
        )
    claimed = (document.get("cycle") or {}).get("sha256") if isinstance(document.get("cycle"), dict) else None
    if claimed is not None and claimed != cyc.sha256:
        raise InvalidInput(
            f"profile.cycle.sha256: the profile is of another cycle ({claimed[:12]}..., this cycle is "
            f"{cyc.sha256[:12]}...)",
            field="profile.cycle.sha256",
        )
    profile = DriveProfile.from_dict(document, cyc.robot)
    legs = _legs(cyc, document.get("legs"), len(profile.t))
    return validate_cycle(profile, cyc.robot, cycle_requirements(cyc, legs))


def _legs(cyc: ResolvedCycle, data: Any, n: int) -> tuple[LegTiming, ...]:
    """The document's legs, checked against the cycle's: names in order, payload states, integer ranges."""
    if not isinstance(data, list) or len(data) != len(LEG_NAMES):
        raise InvalidInput(
            f"profile.legs: expected the {len(LEG_NAMES)} legs {list(LEG_NAMES)}", field="profile.legs"
        )
    out = []
    for i, (entry, name) in enumerate(zip(data, LEG_NAMES, strict=True)):
        where = f"profile.legs[{i}]"
        if not isinstance(entry, dict) or entry.get("name") != name:
            raise InvalidInput(f"{where}.name: expected {name!r}", field=f"{where}.name")
        state = leg(name)
        payload = cyc.spec.unit.id if state.held else None
        if entry.get("payload") != payload:
            raise InvalidInput(
                f"{where}.payload: the {name} leg carries {payload!r} in this cycle, the profile says "
                f"{entry.get('payload')!r}",
                field=f"{where}.payload",
            )
        try:
            s, e = int(entry["sample_start"]), int(entry["sample_end"])
        except (KeyError, TypeError, ValueError):
            raise InvalidInput(
                f"{where}: sample_start and sample_end must be integers", field=where
            ) from None
        if not 0 <= s <= e <= n:
            raise InvalidInput(f"{where}: samples [{s}, {e}) outside the profile's {n}", field=where)
        out.append(
            LegTiming(
                name,
                state.kind,
                payload,
                float(entry.get("t_start_s", 0.0)),
                float(entry.get("t_end_s", 0.0)),
                s,
                e,
            )
        )
    return tuple(out)
