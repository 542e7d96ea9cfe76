"""What every planning stage shares: one plan's context, its clearances, its search preset and its clock.

A stage is a function of the context (and of what the previous stage returned); it records what it did in
``context.report`` and reads its settings from the context, never from loose floats: the clearances
(:class:`Clearances`), the search's steps and work budgets (:class:`SearchPreset`), the time limit. The
context is built once per plan by :meth:`PlanContext.build`; the pipeline runs each stage inside
:meth:`PlanContext.stage`, the stopwatch that announces it to the progress callback and records its run
time in ``report["stages_s"]``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from planner.collision.world import DEFAULT_SELF_CLEARANCE_M, CollisionWorld
from planner.core.exceptions import NoPathFound, NoPathWithinBudget
from planner.core.startup import tune_allocator
from planner.core.types import Array, IntArray
from planner.dynamics.holding import StaticForceCheck
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.dynamics.payload import RigidPayload
from planner.kinematics import chain
from planner.plan.motion import motion_clear
from planner.timing import acc_reference, stages
from planner.timing.stage import TimingFactory

if TYPE_CHECKING:
    from planner.robots.cabin8 import Cabin8
    from planner.scenario.resolve import ResolvedScenario
    from planner.scenario.schema import PlanOptions

Progress = Callable[[str, float], None]

#: Extra clearance the planner keeps beyond the requested one [m], so that the gate's own certification
#: (which must prove a margin at the samples it starts from) passes on the planner's path.
PLANNER_SLACK_M = 0.0015
#: Extra clearance the planner keeps between the robot's own bodies beyond the self-clearance the gate
#: certifies [m] (:data:`~planner.collision.world.DEFAULT_SELF_CLEARANCE_M`, 5 mm, with its 1 mm margin):
#: the planner's walks certify it down to their 0.5 mm margin (:data:`planner.plan.motion.MIN_MARGIN_M`),
#: so its paths keep 6.5 mm, 0.5 mm beyond what the gate proves. Without it a path whose pair of bodies
#: kept 5.59 mm (certified by the planner's walks) failed the gate (gen-cluttered-0-005). It is 0.5 mm
#: below :data:`PLANNER_SLACK_M` so that a start whose bodies keep 6.5 mm can still be left.
PLANNER_SELF_SLACK_M = 0.001
#: What non-adjacent bodies keep from each other in the planner's world [m] (``Clearances.self_planner_m``).
PLANNER_SELF_CLEARANCE_M = DEFAULT_SELF_CLEARANCE_M + PLANNER_SELF_SLACK_M
#: A curved blend is certified with this much more than the planner's clearance [m] (its chords deviate).
BLEND_EXTRA_M = 0.001
#: Fraction of the time limit kept for timing and validation.
TIME_RESERVE = 0.15


def timing_factory(sc: ResolvedScenario) -> TimingFactory:
    """The scenario's timing stage (:func:`planner.timing.stages.select`) at its controller period.

    Raises:
        InvalidInput: a stage the robot cannot run (jerk-limited without jerk limits).
    """
    return stages.select(sc.options.timing, sc.robot).factory(float(sc.options.sample_period_s))


@dataclass(frozen=True)
class Clearances:
    """The clearance settings of one plan, built once from the scenario and passed as one value.

    Attributes:
        requested_m: The scenario's ``clearance`` [m]: what the gate certifies, exactly.
        slack_m: What the planner keeps beyond it [m] (:data:`PLANNER_SLACK_M`).
        motion_margin_m: The certification margin of the planner's motion checks [m] (the scenario's
            ``motion_margin_m``): a certified walk proves ``planner_m`` with this margin at every state.
        blend_extra_m: Extra clearance of a curved blend's certification [m] (:data:`BLEND_EXTRA_M`).
        self_requested_m: What the robot's non-adjacent bodies keep from each other [m]: what the gate
            certifies between them.
        self_slack_m: What the planner keeps beyond it [m] (:data:`PLANNER_SELF_SLACK_M`).
    """

    requested_m: float
    motion_margin_m: float
    slack_m: float = PLANNER_SLACK_M
    blend_extra_m: float = BLEND_EXTRA_M
    self_requested_m: float = DEFAULT_SELF_CLEARANCE_M
    self_slack_m: float = PLANNER_SELF_SLACK_M

    @classmethod
    def of(cls, options: PlanOptions) -> Clearances:
        """The clearances of a scenario's options."""
        return cls(requested_m=float(options.clearance_m), motion_margin_m=float(options.motion_margin_m))

    @property
    def planner_m(self) -> float:
        """The clearance every planner stage certifies [m]: requested + slack."""
        return self.requested_m + self.slack_m

    @property
    def self_planner_m(self) -> float:
        """What the robot's bodies keep from each other in every planner stage [m]: requested + slack."""
        return self.self_requested_m + self.self_slack_m

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
        quick_motion_checks: Motion-check budget of the quick attempt and of a local connection onto or
            off a transit ride.
        full_motion_checks: Motion-check budget of a full attempt (the time limit applies as well; when it
            stops the planner first, the result depends on the machine's speed).
    """

    name: str
    straight: bool = True
    transit: bool = True
    simplify: bool = True
    blends: bool = True
    quick_attempt: bool = True
    planner_range: float | None = 1.0
    quick_motion_checks: int = 1500
    full_motion_checks: int = 40_000


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
class Stopwatch:
    """The run time of one stage (:meth:`PlanContext.stage`), set when the stage ends [s]."""

    name: str
    seconds: float = 0.0


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
        motion_checks_granted: The motion-check budgets of the sampling-planner attempts run so far,
            summed: the work budget a refusal reports.
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
    motion_checks_granted: int = 0
    ticking: tuple[str, float, float] | None = None
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
        tune_allocator()  # the process's large temporaries from the heap (once; see its docstring)
        payload = sc.payload.rigid_payload() if sc.payload is not None else None
        dynamics = Cabin8Dynamics.of(sc.robot)
        clearances = Clearances.of(sc.options)
        ctx = cls(
            sc=sc,
            robot=sc.robot,
            world=sc.world(self_clearance=clearances.self_planner_m),
            dynamics=dynamics,
            payload=payload,
            forces=StaticForceCheck(dynamics, payload),
            clearances=clearances,
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
        acc_reference.kernels()

    # ------------------------------------------------------------------ clock
    def elapsed(self) -> float:
        """Seconds since the plan's clock started."""
        return time.perf_counter() - self.t0

    def remaining(self) -> float:
        """Time left for search [s], keeping :data:`TIME_RESERVE` of the limit for timing and validation."""
        return self.opts.time_limit_s * (1.0 - TIME_RESERVE) - self.elapsed()

    @contextmanager
    def stage(self, name: str, at: float | None = None, until: float | None = None) -> Iterator[Stopwatch]:
        """Run one stage: announce it, time it into ``report["stages_s"][name]`` when it ends normally.

        Args:
            name: The stage's name (the progress callback's and the report's).
            at: The fraction of the plan done when it starts, announced to the progress callback (None:
                not announced, e.g. one try of a repeated stage).
            until: The fraction done when it ends: the stage's work then reports its progress in between
                (:meth:`tick`: the elapsed share of the search's time budget).

        Yields:
            The stage's :class:`Stopwatch` (its ``seconds`` set once the stage ends). A stage that raises
            (a refusal) is not recorded.
        """
        if at is not None:
            self.progress(name, at)
        ticking = self.ticking
        if at is not None and until is not None:
            self.ticking = (name, at, until)
        watch = Stopwatch(name)
        t_start = time.perf_counter()
        try:
            yield watch
        finally:
            self.ticking = ticking
        watch.seconds = time.perf_counter() - t_start
        self.report["stages_s"][name] = round(watch.seconds, 6)

    def tick(self) -> None:
        """Report a ticking stage's progress at most twice a second: the elapsed share of the time budget.

        Only a stage run with ``until`` ticks (the search, between its start and the smoothing's).
        """
        now = time.perf_counter()
        if self.ticking is not None and now - self.last_tick >= 0.5:
            self.last_tick = now
            name, at, until = self.ticking
            budget = self.opts.time_limit_s * (1.0 - TIME_RESERVE)
            self.progress(name, at + (until - at) * min(1.0, self.elapsed() / budget))

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
        """The refusal of a search without a path, saying whether the clock or the work budget ended it.

        The work budget reported is the one in force: the budgets of the sampling-planner attempts this
        search ran (:attr:`motion_checks_granted`; the baseline preset's single attempt: 40 000).
        """
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
        budget = self.motion_checks_granted
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

    # ----------------------------------------------------------------- checks
    def state_ok(self, q: Array) -> bool:
        """A planner state: clear by the planner's clearance and holdable within the force limits."""
        return self.world.is_valid(q, self.clearances.planner_m) and self.forces.ok(q)

    def search_state_ok(self, q: Array) -> bool:
        """The sampling planner's extra state check (static forces), ticking the search's progress."""
        self.tick()
        return self.forces.ok(q)

    def search_states_ok(self, qs: Array) -> NDArray[np.bool_]:
        """:meth:`search_state_ok` of many configurations (N, 8) at once: (N,) verdicts."""
        self.tick()
        return np.asarray(self.forces.ratios(qs) <= self.forces.fraction, dtype=bool)

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
