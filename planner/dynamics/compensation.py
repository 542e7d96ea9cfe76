"""Deflection-compensated goals (paper section 5.2): the command whose static sag lands on the request.

:func:`compensate` iterates on the commanded pose of one goal configuration under a load case of the
stiffness model (:mod:`planner.dynamics.stiffness`); :func:`compensate_goals` moves the planner's goal
candidates (and their approach lines) onto their compensated commands. The tolerances are the gate's:
0.01 mm and 1e-5 rad.

The model is passed in (this module does not import it at run time, so the model module can offer the
thin :func:`planner.dynamics.stiffness.compensate_goal` of its common load case).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.core.exceptions import DeflectionNotCompensated
from planner.core.so3 import matrix_to_quat_wxyz, pose_error
from planner.core.types import Array
from planner.dynamics.beams import deflected_pose
from planner.kinematics import chain
from planner.kinematics.closed_form import redundant_family

if TYPE_CHECKING:
    from planner.dynamics.stiffness import LoadCase, StaticDeflection, StiffnessModel

#: Compensation tolerances of the issue: 0.01 mm and 1e-5 rad (what the gate demands).
COMPENSATION_TOL_M = 1e-5
COMPENSATION_TOL_RAD = 1e-5
#: The compensation iterates ten times further, so a result that just converged never fails the gate.
COMPENSATION_ITERATE_TO = 0.1


@dataclass(frozen=True)
class CompensationStep:
    """One iteration of the goal compensation: the residual of the deflected pose to the request."""

    residual_m: float
    residual_rad: float


@dataclass(frozen=True)
class Compensation:
    """Deflection-compensated goal: the command whose deflected pose is the requested pose.

    Attributes:
        T_base_frame_nominal: The requested pose of the frame (4x4).
        T_base_frame_commanded: The pose to command (4x4).
        q_nominal: The configuration the compensation started from (8,).
        q_commanded: Exact IK of the commanded pose on the same (gamma, d5) (8,).
        deflection: Predicted deflection at the commanded configuration.
        residual_m: |p_deflected - p_requested| [m].
        residual_rad: |log(R_requested R_deflected^T)| [rad].
        iterations: Residual before each correction, then the final one.
    """

    T_base_frame_nominal: Array = field(repr=False)
    T_base_frame_commanded: Array = field(repr=False)
    q_nominal: Array = field(repr=False)
    q_commanded: Array = field(repr=False)
    deflection: StaticDeflection
    residual_m: float
    residual_rad: float
    iterations: tuple[CompensationStep, ...]

    def to_dict(self) -> dict[str, Any]:
        """JSON form: nominal and compensated goals (pose and joints), deflection, iteration log."""
        return {
            "nominal": _pose_dict(self.T_base_frame_nominal) | {"joints": self.q_nominal.tolist()},
            "compensated": _pose_dict(self.T_base_frame_commanded) | {"joints": self.q_commanded.tolist()},
            "predicted_deflection": self.deflection.to_dict(),
            "residual_m": self.residual_m,
            "residual_rad": self.residual_rad,
            "iterations": [
                {"residual_m": s.residual_m, "residual_rad": s.residual_rad} for s in self.iterations
            ],
        }


def _pose_dict(T: Array) -> dict[str, Any]:
    w, x, y, z = matrix_to_quat_wxyz(T[:3, :3])
    return {"position": T[:3, 3].tolist(), "orientation": {"w": w, "x": x, "y": y, "z": z}}


def compensate(
    model: StiffnessModel,
    T_base_frame_goal: Array,
    q_goal: Array,
    load: LoadCase,
    tol_m: float = COMPENSATION_ITERATE_TO * COMPENSATION_TOL_M,
    tol_rad: float = COMPENSATION_ITERATE_TO * COMPENSATION_TOL_RAD,
    max_iterations: int = 20,
) -> Compensation:
    """The commanded pose whose deflected pose is the requested one, and its exact IK near ``q_goal``.

    Fixed-point iteration on the pose: with T_cmd = T_goal first, the configuration is the exact
    closed-form IK of T_cmd on the same redundant coordinates (gamma, d5) as ``q_goal``
    (:func:`~planner.kinematics.closed_form.redundant_family`), its deflected pose T_def = exp(x) T_cmd
    (x the static deflection there), and the residual e = T_goal - T_def (position difference and
    rotation vector, base frame) corrects T_cmd <- exp(e) T_cmd. The deflection changes little with the
    configuration, so the error contracts by about |dx/dq| per step (three or four steps in practice).

    Args:
        model: The stiffness model.
        T_base_frame_goal: Requested pose of the frame (4x4), e.g. the payload frame.
        q_goal: A configuration (8,) reaching ``T_base_frame_goal`` exactly (the planner's goal).
        load: The load case: the payload carried (its weight deflects the robot), the frame (the grasp
            for the payload frame) and any additional wrench at its origin (e.g. an insertion force).
        tol_m: Position residual to reach [m] (default 0.01 mm).
        tol_rad: Orientation residual to reach [rad] (default 1e-5).
        max_iterations: Corrections allowed.

    Raises:
        DeflectionNotCompensated: the residual is still above the tolerances after ``max_iterations``, or
            the commanded configuration leaves the robot's admissible set (``details`` has the log).
    """
    (outcome,) = compensate_many(model, T_base_frame_goal, [q_goal], load, tol_m, tol_rad, max_iterations)
    if isinstance(outcome, DeflectionNotCompensated):
        raise outcome
    return outcome


def compensate_many(
    model: StiffnessModel,
    T_base_frame_goal: Array,
    q_goals: Sequence[Array],
    load: LoadCase,
    tol_m: float = COMPENSATION_ITERATE_TO * COMPENSATION_TOL_M,
    tol_rad: float = COMPENSATION_ITERATE_TO * COMPENSATION_TOL_RAD,
    max_iterations: int = 20,
) -> list[Compensation | DeflectionNotCompensated]:
    """:func:`compensate` of several goal configurations at once: each one's outcome, in order.

    Each candidate iterates exactly as :func:`compensate` alone (the same steps, to the same bits): the
    iterations of the candidates still open are taken together, their inverse kinematics and static
    deflections evaluated in one batched call each (a stiffness evaluation is numpy on small stacks: 1.45
    ms for one configuration, 1.61 ms for three, 2.0 ms for ten). A candidate that converges, or fails,
    leaves the batch with its outcome: its :class:`Compensation`, or the :class:`DeflectionNotCompensated`
    that :func:`compensate` would raise.
    """
    robot = model.robot
    T_ft = np.linalg.inv(load.frame())
    T_goal = np.asarray(T_base_frame_goal, dtype=float)
    goals = [np.asarray(q, dtype=float) for q in q_goals]
    T_cmd = [T_goal.copy() for _ in goals]
    logs: list[list[CompensationStep]] = [[] for _ in goals]
    out: list[Compensation | DeflectionNotCompensated | None] = [None] * len(goals)
    open_ = list(range(len(goals)))
    for it in range(max_iterations + 1):
        if not open_:
            break
        # one 4x4 product each, as a single candidate's (a stacked product may round otherwise)
        T_frames = np.stack([T_cmd[k] @ T_ft for k in open_])
        gamma = np.array([goals[k][chain.GAMMA] for k in open_])
        d5 = np.array([goals[k][chain.D5] for k in open_])
        qs = redundant_family(robot.desc.serial_chain, T_frames, gamma, d5)
        for r, k in enumerate(open_):
            qs[r, chain.THETA6] = goals[k][chain.THETA6] + math.remainder(
                qs[r, chain.THETA6] - goals[k][chain.THETA6], 2 * math.pi
            )
        deflections = model.static_deflections(qs, load)
        still: list[int] = []
        for r, k in enumerate(open_):
            q, log, defl = qs[r].copy(), logs[k], deflections[r]
            e = pose_error(T_goal, deflected_pose(T_cmd[k], defl.twist))
            step = CompensationStep(float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:])))
            log.append(step)
            if step.residual_m <= tol_m and step.residual_rad <= tol_rad:
                bad = robot.violations(q)
                if bad:
                    out[k] = DeflectionNotCompensated(
                        "goal compensation: the commanded configuration violates "
                        + ", ".join(b["name"] for b in bad),
                        violations=bad,
                        iterations=[s.__dict__ for s in log],
                    )
                else:
                    out[k] = Compensation(
                        T_goal, T_cmd[k], goals[k], q, defl, step.residual_m, step.residual_rad, tuple(log)
                    )
                continue
            if it == max_iterations:
                out[k] = DeflectionNotCompensated(
                    f"goal compensation: residual {1e3 * log[-1].residual_m:.4g} mm / "
                    f"{log[-1].residual_rad:.3g} rad after {max_iterations} corrections (tolerance "
                    f"{1e3 * tol_m:g} mm / {tol_rad:g} rad)",
                    iterations=[s.__dict__ for s in log],
                    tol_m=tol_m,
                    tol_rad=tol_rad,
                )
                continue
            T_cmd[k] = deflected_pose(T_cmd[k], e)
            still.append(k)
        open_ = still
    assert all(o is not None for o in out)
    return [o for o in out if o is not None]


# ------------------------------------------------------------------------------------------ planner hook
@dataclass(frozen=True)
class CompensatedGoals:
    """Goal configurations (and approach lines) moved onto their compensated commands.

    ``targets[i]``, ``lines[i]`` and ``compensations[i]`` belong together; candidates whose moved line or
    configuration was rejected are dropped (``rejected`` counts them).
    """

    targets: list[Array]
    lines: list[Any]
    compensations: list[Compensation]
    rejected: int


def compensate_goals(
    model: StiffnessModel,
    targets: list[Array],
    lines: list[Any],
    T_base_payload_goal: Array,
    load: LoadCase,
    accept: Callable[[Array], bool],
) -> CompensatedGoals:
    """Move each goal configuration (and its approach line) onto the command that deflects onto the goal.

    Each candidate's final configuration (the end of its approach line, else the target) is compensated by
    :func:`compensate` under ``load`` (the payload and its grasp) on its own (gamma, d5), all candidates
    together (:func:`compensate_many`). The whole line is
    shifted by the same joint offset dq = q_commanded - q_goal: a fixed-redundancy line stays a straight
    joint segment whose payload path is the requested insertion line moved by the goal's correction (the
    deflection along the line changes little; it is reported with the plan). ``accept(path (K, 8)) ->
    bool`` re-checks each moved line (or the single configuration) for limits, force and clearance.

    Raises:
        DeflectionNotCompensated: no candidate can be compensated and accepted (``details`` says why).
    """
    out_t: list[Array] = []
    out_l: list[Any] = []
    comps: list[Compensation] = []
    errors: list[str] = []
    rejected = 0
    paths = [getattr(line, "line", None) if line is not None else None for line in lines]
    ends = [path[-1] if path is not None else q for q, path in zip(targets, paths, strict=True)]
    outcomes = compensate_many(model, T_base_payload_goal, ends, load)  # all at once: the same bits
    for q, line, path, q_end, comp in zip(targets, lines, paths, ends, outcomes, strict=True):
        if isinstance(comp, DeflectionNotCompensated):
            errors.append(comp.message)
            continue
        dq = comp.q_commanded - q_end
        moved = (path if path is not None else q[None, :]) + dq[None, :]
        if not accept(moved):
            rejected += 1
            continue
        out_l.append(dataclasses.replace(line, line=moved, q=line.q + dq) if path is not None else line)
        out_t.append(moved[0])
        comps.append(comp)
    if not out_t:
        raise DeflectionNotCompensated(
            "goal compensation: no goal configuration can be moved onto its deflection-compensated command "
            f"({rejected} rejected for limits, force or clearance; {len(errors)} did not converge)",
            rejected=rejected,
            errors=errors[:3],
        )
    return CompensatedGoals(out_t, out_l, comps, rejected)
