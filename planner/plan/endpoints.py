"""The start and goal configurations of a plan: admissible, clear, holdable, or refused with the evidence."""

from __future__ import annotations

import numpy as np

from planner.core.exceptions import GoalInCollision, GoalUnreachable, StartInvalid
from planner.core.types import Array
from planner.gate.checks import deflected_joints
from planner.gate.requirements import GATE_MOTION_MARGIN_M
from planner.plan.context import PlanContext

#: The gate also certifies the robot sagging under its predicted static deflection (a few mm at the
#: payload, milliradians in the joints): an end configuration whose limit margins (in their own units) are
#: below this, or that is within this of the clearance or the self-clearance [m], is checked sagging too
#: (else the check, tens of milliseconds, cannot fail and is skipped).
SAG_SCREEN = 0.02


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
    check_sagging(ctx, q, what)


def check_sagging(ctx: PlanContext, q: Array, what: str) -> None:
    """Refuse an end configuration the gate's certified walk cannot start or end at, rigid or sagging.

    The gate certifies the requested clearance and the self-clearance with its own margin
    (:data:`~planner.gate.requirements.GATE_MOTION_MARGIN_M`) at every sample it starts a run from, and
    does so for the rigid robot and, with a payload and the robot's stiffness data, for the robot sagging
    under its predicted static deflection (:func:`~planner.gate.checks.deflected_joints`). An end
    configuration that fails there can never pass, whatever the path, so this is said now, with the cause.
    The sagging robot is only checked near a limit, the clearance or the self-clearance
    (:data:`SAG_SCREEN`).

    Raises:
        StartInvalid: the start fails (``start_outside_limits`` for a limit of the sagging robot).
        GoalUnreachable, GoalInCollision: the goal fails by a limit, or by a distance.
    """
    sc, world, c = ctx.sc, ctx.world, ctx.clearances
    margin = GATE_MOTION_MARGIN_M
    own = c.self_requested_m  # what the gate certifies (the planner's world keeps more)
    rep = world.check_motion(q, q, c.requested_m, margin, self_clearance=own)
    sag, q_def = 0.0, np.atleast_2d(q)
    if rep.valid:
        if sc.payload is None or ctx.payload is None or ctx.robot.desc.stiffness is None:
            return
        near_limit = float(np.nanmin(ctx.robot.margins(q))) < SAG_SCREEN
        screen = world.check_motion(q, q, c.requested_m + SAG_SCREEN, margin, self_clearance=own + SAG_SCREEN)
        if not near_limit and screen.valid:
            return
        q_def, sag = deflected_joints(ctx.robot, np.atleast_2d(q), ctx.payload, sc.payload.T_tool_payload)
        rep = world.check_motion(q_def[0], q_def[0], c.requested_m, margin, self_clearance=own)
        if rep.valid:
            return
    limits = any(x.kind == "limit" for x in rep.contacts)
    q_at = q_def[0] if sag > 0.0 else np.asarray(q, dtype=float)
    what_fails = rep.contacts[0].detail if rep.contacts else "no certified clearance"
    if rep.contacts and not limits:  # the exact distance of the closest bodies, against the one required
        d = world.min_distance(q_at, include_self=rep.contacts[0].kind == "self")
        env = world.is_environment(d.bodies[1])
        required = (c.requested_m if env else own) + margin
        other = "the cabin" if d.bodies[1] == "cabin" else d.bodies[1]
        what_fails = (
            f"{d.bodies[0]} {1e3 * d.distance_m:.1f} mm from {other}, {1e3 * required:.1f} mm required (the "
            f"gate certifies the clearance or self-clearance with a {1e3 * margin:g} mm margin)"
        )
    how = (
        f"sagging under the payload as the stiffness model predicts ({1e3 * sag:.2f} mm at the payload; the "
        "gate certifies the sagging robot too), the robot has"
        if sag > 0.0
        else "the robot has"
    )
    msg = f"{what}: {how} {what_fails}"
    contacts = [x.to_dict() for x in rep.contacts]
    if what == "start":
        raise StartInvalid(msg, limits=limits, contacts=contacts, sag_m=sag)
    if limits:
        raise GoalUnreachable(msg, contacts=contacts, sag_m=sag)
    raise GoalInCollision(msg, contacts=contacts, sag_m=sag)
