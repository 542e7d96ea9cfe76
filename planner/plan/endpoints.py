"""The start and goal configurations of a plan: admissible, clear, holdable, or refused with the evidence."""

from __future__ import annotations

from planner.core.exceptions import GoalInCollision, GoalUnreachable, StartInvalid
from planner.core.types import Array
from planner.plan.context import PlanContext


def check_configuration(ctx: PlanContext, q: Array, what: str) -> None:
    """Refuse an end configuration (``what``: ``"start"`` or ``"goal"``) the planner cannot start or end at.

    It must satisfy every admissibility limit, keep the requested clearance, keep the planner's slack
    beyond it (every motion is certified with it: an end state inside that band can never be left or
    reached, so this is said now rather than searched for until the time limit) and be statically holdable.

    Raises:
        StartInvalid: the start fails (``limits=True`` for a limit or force refusal).
        GoalUnreachable: the goal violates a limit or cannot be held.
        GoalInCollision: the goal comes within the clearance (or the planner's slack).
    """
    world, c = ctx.world, ctx.clearances
    rep = world.check_state(q, c.requested_m, all_contacts=True)
    limits = [x for x in rep.contacts if x.kind == "limit"]
    contacts = [x.to_dict() for x in rep.contacts]
    if what == "start":
        if limits:
            raise StartInvalid(
                f"start violates {', '.join(x.detail for x in limits)}", limits=True, contacts=contacts
            )
        if rep.contacts:
            raise StartInvalid(f"start: {rep.contacts[0].detail}", contacts=contacts)
    else:
        if limits:
            raise GoalUnreachable(f"goal violates {', '.join(x.detail for x in limits)}", contacts=contacts)
        if rep.contacts:
            raise GoalInCollision(f"goal: {rep.contacts[0].detail}", contacts=contacts)
    slack = world.check_state(q, c.planner_m)
    if not slack.valid:
        msg = (
            f"{what}: {slack.contacts[0].detail}: the planner keeps {1e3 * c.slack_m:.0f} mm beyond "
            f"the requested {c.requested_m} m so that the gate can certify the motion; "
            f"ask for a smaller clearance or move the {what}"
        )
        if what == "start":
            raise StartInvalid(msg, contacts=[x.to_dict() for x in slack.contacts])
        raise GoalInCollision(msg, contacts=[x.to_dict() for x in slack.contacts])
    forces = ctx.forces
    ratio = float(forces.ratios(q)[0])
    if ratio > forces.fraction:
        msg = (
            f"{what}: holding the payload there needs {100 * ratio:.0f}% of a drive's force limit "
            f"(at most {100 * forces.fraction:.0f}% allowed)"
        )
        if what == "start":
            raise StartInvalid(msg, limits=True, static_force_ratio=ratio)
        raise GoalUnreachable(msg, static_force_ratio=ratio)
