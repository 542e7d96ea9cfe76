"""The one use case behind CLI ``check`` and ``POST /plans:validate``: a caller's profile through the gate."""

from __future__ import annotations

from typing import Any

from planner.core.exceptions import InvalidInput
from planner.gate.checks import GateReport, validate_profile
from planner.gate.requirements import requirements_for
from planner.scenario.resolve import ResolvedScenario
from planner.timing.profile import DriveProfile


def check_profile(sc: ResolvedScenario, document: dict[str, Any]) -> GateReport:
    """Run the validation gate on a drive-profile document (as written by ``plan``) for a scenario.

    The gate trusts nothing the planner computed: the collision world, the payload and the requirements are
    rebuilt here from the scenario alone.

    Args:
        sc: The resolved scenario the profile claims to solve.
        document: The profile document (JSON object with ``status``, ``t_s`` and the drive arrays).

    Raises:
        InvalidInput: the document is a refusal or not a profile of this scenario's robot (the field named).
    """
    if not isinstance(document, dict) or document.get("status", "succeeded") != "succeeded":
        raise InvalidInput(
            "profile: not a drive profile (a refusal document or not a JSON object)", field="profile.status"
        )
    profile = DriveProfile.from_dict(document, sc.robot)
    payload = sc.payload.rigid_payload() if sc.payload is not None else None
    world = sc.world()
    return validate_profile(profile, sc.robot, world, requirements_for(sc, payload))
