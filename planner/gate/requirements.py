"""What a profile must satisfy for a scenario, and the gate's own tolerances.

The gate's constants live here, with the measurement that chose them; :func:`requirements_for` turns a
resolved scenario into the :class:`GateRequirements` every route to the gate uses (the planner, CLI
``check`` and ``POST /plans:validate`` through :mod:`planner.gate.check_profile`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.collision.world import DEFAULT_SELF_CLEARANCE_M
from planner.core.description import TRUSTED_STIFFNESS_SOURCES
from planner.core.exceptions import InvalidInput
from planner.core.types import Array, IntArray
from planner.dynamics.payload import RigidPayload
from planner.timing import stages

if TYPE_CHECKING:
    from planner.scenario.resolve import ResolvedScenario
    from planner.timing.path import JointPath

#: Certification margin of the gate's collision check [m]: the certified walk proves the requested
#: clearance with this margin at the states it starts from (the scenario's ``motion_margin_m`` is the
#: planner's, not the gate's).
GATE_MOTION_MARGIN_M = 0.001
LIMIT_TOLERANCE = 0.01  # 1% above velocity / acceleration / force limits
GOAL_POSITION_TOL_M = 1e-3
GOAL_ANGLE_TOL_RAD = np.deg2rad(0.1)
LINE_TOL_M = 1e-3
#: The sampled joint positions may lie this far off the certified path (joint space, m and rad).
PATH_DEVIATION_TOL = 1e-6
#: Along the insertion the payload may not step back out of the bay by more than this [m] (rounding).
APPROACH_BACKOUT_TOL_M = 1e-9
START_TOL = 1e-9
#: Largest extra clearance a run of samples may cost in the certified collision check [m], and the
#: longest run: a run that fails is retried in halves, so a larger extra costs no verdict, only fewer,
#: longer certified chords where the path has room (measured on the reference scenarios: 0.5 mm and 32
#: samples took twice as long as 2 mm and 128).
GATE_MAX_EXTRA_M = 0.002
GATE_MAX_RUN = 128
#: The reported acceleration may differ from the step's mean acceleration dv/dt by this fraction of a_max
#: (the time law's acceleration is piecewise constant and may switch within a step; the executed dv/dt
#: itself is held to the 1% limit tolerance by the acceleration check).
ACC_CONSISTENCY = 0.05


@dataclass(frozen=True)
class GateRequirements:
    """What the trajectory must do, from the scenario."""

    start_u: Array = field(repr=False)
    clearance_m: float
    motion_margin_m: float
    goal_u: Array | None = field(default=None, repr=False)
    T_base_payload_goal: Array | None = field(default=None, repr=False)
    T_tool_payload: Array = field(default_factory=lambda: np.eye(4), repr=False)
    approach_direction: Array | None = field(default=None, repr=False)
    approach_distance_m: float = 0.0
    payload: RigidPayload | None = None
    #: Deflection compensation of a pose goal: the final sample must reach the commanded payload pose
    #: (kinematically) and its predicted deflected pose the requested one. The commanded pose is the
    #: planner's; without it the gate recomputes it from the final sample's redundant coordinates.
    compensate_deflection: bool = False
    T_base_payload_commanded: Array | None = field(default=None, repr=False)
    #: Also certify the *deflected* robot (the static sag predicted by the stiffness model, see
    #: :func:`deflected_joints`) keeping the clearance; needs a payload and the robot's stiffness data.
    deflection_check: bool = False
    #: The controller period the scenario asks for [s]: the profile must be sampled at exactly it (a
    #: profile timed at another period runs faster or slower on the controller than it was checked).
    sample_period_s: float | None = None
    #: Whether the drive jerk limits bind (the timing stage's ``binds_jerk``, :mod:`planner.timing.stages`).
    jerk_limited: bool = True
    #: The certified geometric path, leg by leg: when given, every sample must lie on it
    #: (:data:`PATH_DEVIATION_TOL`). The planner passes it; a caller's profile (CLI ``check``) has none.
    path_legs: tuple[JointPath, ...] | None = field(default=None, repr=False)
    #: The leg (N,) each sample was timed on, with ``path_legs``: each sample must lie on its own leg.
    path_leg_of: IntArray | None = field(default=None, repr=False)
    #: With ``path_leg_of``: the parameter (N,) on its leg at which each sample was taken, the witness that
    #: it lies on the path (a sample within the tolerance of its witness point needs no nearest-point search).
    path_s: Array | None = field(default=None, repr=False)
    #: Whether this gate certifies the clearance (``collision`` and the clearance figure); False only where
    #: a caller's gate certifies the same samples in the same world (a cycle's legs: the cycle gate).
    collision: bool = True
    #: What non-adjacent bodies of the robot must keep from each other [m], certified with
    #: ``motion_margin_m`` as the cabin's clearance: the requested one, whatever the world's own setting (the
    #: planner's world keeps more, :data:`planner.plan.context.PLANNER_SELF_CLEARANCE_M`).
    self_clearance_m: float = DEFAULT_SELF_CLEARANCE_M


#: Samples of a profile at which the static deflection is predicted (the gate's deflected collision check,
#: the plan's report), interpolated in between: the deflection is a smooth function of the configuration.
DEFLECTION_SAMPLES = 300
#: ... and at most one per this much motion of the largest non-rail joint [rad or m]: the deflection does
#: not depend on the rail position (the whole robot moves with the carriage), and it changes smoothly with
#: the others. Measured against the prediction at every sample (the suite's pose-goal plans, the aisle
#: cycle's legs): the payload frame's interpolated sag within 1.5 um (the even samples alone: 0.06 um).
DEFLECTION_STEP = 0.002


def deflection_sample_indices(q: Array) -> IntArray:
    """Indices (K,) of the samples of joint samples q (N, 8) at which the deflection is predicted.

    Up to :data:`DEFLECTION_SAMPLES` evenly spaced samples, of which only the first after each
    :data:`DEFLECTION_STEP` of motion of the largest non-rail joint is kept (a dwell or a short line needs
    a few, not hundreds); the first and the last sample always.
    """
    from planner.kinematics import chain

    q = np.asarray(q, dtype=float)
    n = len(q)
    even = np.arange(0, n, max(1, n // DEFLECTION_SAMPLES))
    if n > 1:
        step = np.abs(np.diff(np.delete(q, chain.D1, axis=1), axis=0)).max(axis=1)
        travel = np.concatenate([[0.0], np.cumsum(step)])
        _, first = np.unique(np.floor(travel[even] / DEFLECTION_STEP), return_index=True)
        even = even[first]
    return np.unique(np.concatenate([even, [0, n - 1]])).astype(np.int64)


def compensates_deflection(sc: ResolvedScenario) -> bool:
    """Whether a scenario's pose goal is deflection-compensated.

    The option decides when given; by default (null) a pose goal with a payload is compensated only when
    the robot's stiffness data are trustworthy (``stiffness.source`` paper-fit or calibrated, issue 15):
    compensating with guessed data can make the placement worse than not compensating.

    Raises:
        InvalidInput: compensation asked for explicitly on a robot without stiffness data.
    """
    option = sc.options.compensate_deflection
    if option and sc.robot.desc.stiffness is None:
        raise InvalidInput(
            f"options.compensate_deflection: robot {sc.robot.name!r} has no stiffness data",
            field="options.compensate_deflection",
        )
    spec = sc.robot.desc.stiffness
    if sc.T_base_payload_goal is None or spec is None:
        return False
    if option is None:
        return sc.payload is not None and spec.source in TRUSTED_STIFFNESS_SOURCES
    return bool(option)


#: The stiffness model's name in plan reports and provenance.
STIFFNESS_MODEL_NAME = "cabin8 beam/spring/pin stiffness model (paper section 4, planner.dynamics.stiffness)"


def stiffness_provenance(sc: ResolvedScenario) -> dict[str, Any]:
    """Which stiffness model and data a plan used, and whether its goal was compensated (issue 15).

    ``{"model", "source", "compensated", "note"}``; ``source`` is None without stiffness data.
    """
    spec = sc.robot.desc.stiffness
    compensated = compensates_deflection(sc)
    if spec is None:
        return {"model": None, "source": None, "compensated": False, "note": "no stiffness data"}
    if compensated and spec.source not in TRUSTED_STIFFNESS_SOURCES:
        note = (
            f"compensated on request with {spec.source} stiffness data (guesses): the command may "
            "miss the request by more than the predicted sag"
        )
    elif compensated:
        note = f"goal compensated with {spec.source} stiffness data"
    elif sc.T_base_payload_goal is not None and sc.payload is not None:
        note = (
            f"not compensated: the stiffness data are {spec.source} (not fitted to the paper nor "
            "calibrated); the predicted sag is reported, set options.compensate_deflection: true to "
            "compensate anyway, or calibrate the robot (cabinplan stiffness calibrate)"
        )
    else:
        note = "not compensated"
    return {"model": STIFFNESS_MODEL_NAME, "source": spec.source, "compensated": compensated, "note": note}


def requirements_for(
    sc: ResolvedScenario, payload: RigidPayload | None, T_base_payload_commanded: Array | None = None
) -> GateRequirements:
    """What the validation gate demands of any trajectory for this scenario.

    ``T_base_payload_commanded`` is the planner's compensated command of a pose goal (the gate
    recomputes it from the final sample when it is not given).
    """
    return GateRequirements(
        start_u=sc.start_u,
        clearance_m=sc.options.clearance_m,
        motion_margin_m=GATE_MOTION_MARGIN_M,
        goal_u=sc.goal_u,
        T_base_payload_goal=sc.T_base_payload_goal,
        T_tool_payload=sc.payload.T_tool_payload if sc.payload is not None else np.eye(4),
        approach_direction=sc.approach_direction,
        approach_distance_m=sc.approach_distance_m,
        payload=payload,
        compensate_deflection=compensates_deflection(sc),
        T_base_payload_commanded=T_base_payload_commanded,
        sample_period_s=sc.options.sample_period_s,
        deflection_check=sc.payload is not None and sc.robot.desc.stiffness is not None,
        jerk_limited=stages.select(sc.options.timing, sc.robot).binds_jerk,
        collision=sc.gate_collision,
    )
