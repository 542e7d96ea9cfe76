"""What every planning stage shares: one plan's context, its clearances, its search preset and its clock.

A stage is a function of the context (and of what the previous stage returned); it records what it did in
``context.report`` and reads its settings from the context, never from loose floats. The context is built
once per plan by :meth:`PlanContext.build`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.collision.world import CollisionWorld
from planner.core.exceptions import NoPathFound, NoPathWithinBudget
from planner.core.types import Array, IntArray
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.dynamics.payload import RigidPayload
from planner.gate.requirements import timing_of
from planner.kinematics import chain
from planner.plan.goals import StaticForceCheck
from planner.plan.motion import motion_clear
from planner.timing import reference
from planner.timing.jerk import JerkLimitedStage
from planner.timing.stage import TimingFactory, TimingStage
from planner.timing.toppra import ToppraStage

if TYPE_CHECKING:
    from planner.robots.cabin8 import Cabin8
    from planner.scenario.resolve import ResolvedScenario
    from planner.scenario.schema import PlanOptions

Progress = Callable[[str, float], None]

#: Extra clearance the planner keeps beyond the requested one [m], so that the gate's own certification
#: (which must prove a margin at the samples it starts from) passes on the planner's path.
PLANNER_SLACK_M = 0.0015
#: A curved blend is certified with this much more than the planner's clearance [m] (its chords deviate).
BLEND_EXTRA_M = 0.001
#: Fraction of the time limit kept for timing and validation.
TIME_RESERVE = 0.15


def timing_factory(sc: ResolvedScenario) -> TimingFactory:
    """The scenario's timing stage (``options.timing``, :func:`~planner.gate.requirements.timing_of`).

    ``jerk_limited``: :class:`~planner.timing.jerk.JerkLimitedStage` checked at the scenario's controller
    period; ``acceleration_limited``: :class:`~planner.timing.toppra.ToppraStage`.
    """
    if timing_of(sc) == "acceleration_limited":
        return ToppraStage
    period = float(sc.options.sample_period_s)

    def jerk_stage(robot: Any, payload: Any, safety: tuple[float, float, float]) -> TimingStage:
        return JerkLimitedStage(robot, payload, safety, sample_period_s=period)

    return jerk_stage


@dataclass(frozen=True)
class Clearances:
    """The clearance settings of one plan, built once from the scenario and passed as one value.

    Attributes:
        requested_m: The scenario's ``clearance`` [m]: what the gate certifies, exactly.
        slack_m: What the planner keeps beyond it [m] (:data:`PLANNER_SLACK_M`).
        motion_margin_m: The certification margin of the planner's motion checks [m] (the scenario's
            ``motion_margin_m``): a certified walk proves ``planner_m`` with this margin at every state.
        blend_extra_m: Extra clearance of a curved blend's certification [m] (:data:`BLEND_EXTRA_M`).
    """

    requested_m: float
    motion_margin_m: float
    slack_m: float = PLANNER_SLACK_M
    blend_extra_m: float = BLEND_EXTRA_M

    @classmethod
    def of(cls, options: PlanOptions) -> Clearances:
        """The clearances of a scenario's options."""
        return cls(requested_m=float(options.clearance_m), motion_margin_m=float(options.motion_margin_m))

    @property
    def planner_m(self) -> float:
        """The clearance every planner stage certifies [m]: requested + slack."""
        return self.requested_m + self.slack_m

    @property
    def blend_m(self) -> float:
        """The clearance a curved blend is certified with [m]."""
        return self.planner_m + self.blend_extra_m


@dataclass(frozen=True)
class SearchPreset:
    """Which search and smoothing steps a plan uses: the product's, or the benchmark baseline's.

    Attributes:
        name: ``"product"`` or ``"baseline"``.
        straight: Try the straight joint motion first.
        transit: Try a transit posture for long rail moves.
        simplify: Shortcut / simplify paths and cut corners for time (also needs ``options.simplify``).
        blends: Blend corners (else the robot stops at every waypoint).
        quick_attempt: A first OMPL attempt with the small, reproducible motion-check budget.
        planner_range: OMPL's step length in scaled joint space (None: OMPL's default).
    """

    name: str
    straight: bool = True
    transit: bool = True
    simplify: bool = True
    blends: bool = True
    quick_attempt: bool = True
    planner_range: float | None = 1.0


#: The product: every step (planner range 1.0: measured on the reference bay insertions, it halves the
#: median search time against OMPL's default).
PRODUCT = SearchPreset("product")
#: The benchmark's baseline: OMPL with OMPL's defaults, its raw path, no straight-line, transit or shortcut
#: steps, no corner blends (the robot stops at every waypoint); the gate still decides.
BASELINE = SearchPreset(
    "baseline",
    straight=False,
    transit=False,
    simplify=False,
    blends=False,
    quick_attempt=False,
    planner_range=None,
)


@dataclass
class PlanContext:
    """One plan's shared state: scenario, robot, world, forces, clearances, preset, clock and report.

    Attributes:
        sc: The resolved scenario.
        robot: Its robot model.
        world: The collision world (cabin, payload, robot bodies).
        dynamics: The robot's inverse dynamics.
        payload: The payload's rigid-body data (None without a payload).
        forces: The static-force check every planner state passes.
        clearances: The clearance settings.
        preset: The search preset.
        timing: Factory of the timing stage ``(robot, payload, safety) -> TimingStage``.
        progress: Called with (stage name, fraction done) as the stages start.
        t0: The plan's clock origin (``time.perf_counter``), set after the warm-up.
        report: What the stages did (JSON-able), returned with the result.
    """

    sc: ResolvedScenario
    robot: Cabin8
    world: CollisionWorld
    dynamics: Cabin8Dynamics
    payload: RigidPayload | None
    forces: StaticForceCheck
    clearances: Clearances
    preset: SearchPreset
    timing: TimingFactory
    progress: Progress
    t0: float = 0.0
    report: dict[str, Any] = field(default_factory=lambda: {"stages_s": {}})
    last_tick: float = 0.0
    #: The leg index (N,) of every sample of the last profile the timing stage sampled (None before).
    leg_of: IntArray | None = None

    @classmethod
    def build(
        cls,
        sc: ResolvedScenario,
        progress: Progress | None = None,
        timing: TimingFactory | None = None,
        preset: SearchPreset = PRODUCT,
    ) -> PlanContext:
        """The context of a plan of ``sc``: world and dynamics built, kernels warmed up, clock started."""
        payload = sc.payload.rigid_payload() if sc.payload is not None else None
        dynamics = Cabin8Dynamics.of(sc.robot)
        ctx = cls(
            sc=sc,
            robot=sc.robot,
            world=sc.world(),
            dynamics=dynamics,
            payload=payload,
            forces=StaticForceCheck(dynamics, payload),
            clearances=Clearances.of(sc.options),
            preset=preset,
            timing=timing or timing_factory(sc),
            progress=progress or (lambda stage, fraction: None),
        )
        ctx.warm_up(sc.start_q)
        ctx.t0 = ctx.last_tick = time.perf_counter()
        return ctx

    @property
    def opts(self) -> PlanOptions:
        """The scenario's options."""
        return self.sc.options

    @property
    def simplify(self) -> bool:
        """Whether paths are shortcut, simplified and corner-cut (preset and scenario option)."""
        return self.preset.simplify and self.opts.simplify

    def warm_up(self, q: Array) -> None:
        """Run one state and one motion check before the clock starts (results unused).

        The first kernel call loads the ahead-of-time build of the collision kernels (under a
        millisecond), or builds it first where it is missing (a fresh install that skipped ``make``:
        about half a minute), or compiles them with numba's JIT where no build can be made; none of
        that may count against the scenario's planning time limit. The timing kernels are loaded here
        too. Once loaded, this costs well under a millisecond.
        """
        q_b = np.array(q, dtype=float)
        q_b[chain.THETA6] += 1e-3
        c = self.clearances
        self.world.is_valid(q, c.planner_m)
        self.world.check_motion(q, q_b, c.planner_m, c.motion_margin_m)
        # The kernels the later stages call first (batch poses and sphere covers, the exact-distance state,
        # the path runs): loading each from numba's disk cache takes 5-25 ms in a fresh process, which
        # was counted in the planning time of the first plan of every process (a CLI call: each plan).
        self.world.cover_centres(np.stack([q, q_b]))
        self.world.check_path(np.stack([q, q_b, q]), c.requested_m, c.motion_margin_m)
        if self.world.cabin is not None:
            self.world.min_distance(q, include_self=False)
        reference.kernels()

    # ------------------------------------------------------------------ clock
    def elapsed(self) -> float:
        """Seconds since the plan's clock started."""
        return time.perf_counter() - self.t0

    def remaining(self) -> float:
        """Time left for search [s], keeping :data:`TIME_RESERVE` of the limit for timing and validation."""
        return self.opts.time_limit_s * (1.0 - TIME_RESERVE) - self.elapsed()

    def tick(self) -> None:
        """Report the search's progress at most twice a second: the elapsed share of its time budget."""
        now = time.perf_counter()
        if now - self.last_tick >= 0.5:
            self.last_tick = now
            budget = self.opts.time_limit_s * (1.0 - TIME_RESERVE)
            self.progress("search", 0.15 + 0.55 * min(1.0, self.elapsed() / budget))

    def out_of_time(self) -> bool:
        """The deadline of the search's steps: raises the time-limit refusal once the time is up.

        A step cut short by the clock would give a result that depends on the machine's speed and load, so
        the wall-clock limit stops the plan instead of shortening it; the search itself is bounded by its
        work budgets (motion checks), so the same scenario and seed give the same plan on any machine.

        Raises:
            NoPathFound: the time is up (``details['ended_by'] == 'time_limit'``).
        """
        self.tick()
        if self.remaining() <= 0:
            raise self.no_path()
        return False

    def no_path(self) -> NoPathFound:
        """The refusal of a search without a path, saying whether the clock or the work budget ended it."""
        from planner.plan import connect

        elapsed = round(self.elapsed(), 3)
        planner = self.opts.planner
        if self.remaining() <= 0:
            return NoPathFound(
                f"the wall-clock time limit ({self.opts.time_limit_s:g} s) stopped the search after "
                f"{elapsed:g} s, before its work budget was spent (the machine was slower or busier than "
                f"it needs): retry, or raise options.time_limit_s",
                ended_by="time_limit",
                time_limit_s=self.opts.time_limit_s,
                elapsed_s=elapsed,
                planner=planner,
            )
        budget = connect.QUICK_MOTION_CHECKS + connect.FULL_MOTION_CHECKS
        return NoPathWithinBudget(
            f"no collision-free path found within the search's work budget ({budget} motion checks, "
            f"planner {planner}); the same seed ends the same way on any machine: try another options.seed "
            "or scenario",
            ended_by="work_budget",
            motion_check_budget=budget,
            time_limit_s=self.opts.time_limit_s,
            elapsed_s=elapsed,
            planner=planner,
        )

    def stage_done(self, name: str, t_start: float) -> None:
        """Record a stage's run time (from ``t_start``, a ``time.perf_counter`` reading) in the report."""
        self.report["stages_s"][name] = round(time.perf_counter() - t_start, 6)

    # ----------------------------------------------------------------- checks
    def state_ok(self, q: Array) -> bool:
        """A planner state: clear by the planner's clearance and holdable within the force limits."""
        return self.world.is_valid(q, self.clearances.planner_m) and self.forces.ok(q)

    def search_state_ok(self, q: Array) -> bool:
        """The sampling planner's extra state check (static forces), ticking the search's progress."""
        self.tick()
        return self.forces.ok(q)

    def search_motion_ok(self, q_a: Array, q_b: Array) -> bool:
        """The sampling planner's extra motion check (static forces along it), ticking the progress."""
        self.tick()
        return self.forces.segment_ok(q_a, q_b)

    def motion_ok(self, q_a: Array, q_b: Array) -> bool:
        """A planner motion: certified clear by the planner's clearance, holdable along its length."""
        self.tick()
        c = self.clearances
        return motion_clear(self.world, q_a, q_b, c.planner_m, c.motion_margin_m) and self.forces.segment_ok(
            q_a, q_b
        )
