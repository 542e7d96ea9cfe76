"""Plots of a drive profile against its limits, and of the clearance along the path (matplotlib, Agg).

Kept at the edge: nothing in the planning core imports this module.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from planner.core.types import Array
from planner.documents.figures import png_bytes
from planner.robots.cabin8 import Cabin8  # noqa: E402
from planner.timing.profile import DriveProfile  # noqa: E402

if TYPE_CHECKING:
    from planner.collision.world import CollisionWorld
    from planner.plan.pipeline import PlanResult
    from planner.scenario.resolve import ResolvedScenario


def profile_png(
    profile: DriveProfile,
    robot: Cabin8,
    clearance_t: Array | None = None,
    clearance_m: Array | None = None,
    required_clearance_m: float | None = None,
    title: str = "",
    deflection: Array | None = None,
) -> bytes:
    """PNG bytes of the profile against its limits.

    Positions (fraction of travel), velocity / acceleration / jerk (the change of the sampled
    acceleration, with jerk limits) / effort as fractions of their limits per drive, the clearance to
    the cabin along the path (if given) with the required clearance, and the
    predicted static deflection (if given: (N, 6) twists at the profile's samples, translation [m] and
    rotation [rad]) as its translation norm [mm] and rotation norm [mrad].
    """
    lim = robot.limits
    jerk = lim.j_max is not None
    rows = 4 + jerk + (clearance_m is not None) + (deflection is not None)
    fig, axes = plt.subplots(rows, 1, figsize=(11, 2.6 * rows), sharex=True)
    t = profile.t
    names = profile.drive_names
    ax = axes[0]
    span = np.maximum(lim.upper - lim.lower, 1e-9)
    for j, n in enumerate(names):
        ax.plot(t, (profile.position[:, j] - lim.lower[j]) / span[j], label=n, lw=1)
    ax.set_ylabel("position\n(fraction of travel)")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(ncol=8, fontsize=7, loc="upper center")
    panels: list[tuple[Array | None, Array, str]] = [
        (profile.velocity, lim.v_max, "velocity / v_max"),
        (profile.acceleration, lim.a_max, "acceleration / a_max"),
    ]
    if lim.j_max is not None:
        panels.append((profile.jerk, lim.j_max, "jerk / j_max"))
    panels.append((profile.effort, lim.effort_max, "effort / effort_max"))
    for ax, (values, limit, label) in zip(axes[1:], panels, strict=False):
        if values is None:  # a profile without forces
            ax.text(0.5, 0.5, "no force model", transform=ax.transAxes, ha="center")
            continue
        for j, n in enumerate(names):
            ax.plot(t, values[:, j] / limit[j], lw=1, label=n)
        ax.axhline(1.0, color="red", lw=0.8, ls="--")
        ax.axhline(-1.0, color="red", lw=0.8, ls="--")
        ax.set_ylabel(label)
        ax.set_ylim(-1.15, 1.15)
    if clearance_m is not None and clearance_t is not None:
        ax = axes[4 + jerk]
        ax.plot(clearance_t, 1e3 * np.asarray(clearance_m), color="black", lw=1)
        if required_clearance_m is not None:
            ax.axhline(1e3 * required_clearance_m, color="red", lw=0.8, ls="--", label="required")
            ax.legend(fontsize=7)
        ax.set_ylabel("clearance [mm]")
        ax.set_ylim(bottom=0)
    if deflection is not None:
        ax = axes[-1]
        x = np.asarray(deflection)
        ax.plot(t, 1e3 * np.linalg.norm(x[:, :3], axis=1), color="tab:blue", lw=1, label="translation [mm]")
        ax.plot(t, 1e3 * np.linalg.norm(x[:, 3:], axis=1), color="tab:orange", lw=1, label="rotation [mrad]")
        ax.set_ylabel("static deflection")
        ax.set_ylim(bottom=0)
        ax.legend(fontsize=7)
    axes[-1].set_xlabel("t [s]")
    return png_bytes(fig, title)


def plan_png(sc: ResolvedScenario, result: PlanResult, world: CollisionWorld) -> bytes:
    """PNG bytes of a validated plan: :func:`profile_png` with the clearance along the path.

    The clearance (exact distances, :meth:`CollisionWorld.clearance_profile`) is measured at about 200
    samples (every ``N // 200``-th and the last) when the scenario has a cabin.

    Args:
        sc: The resolved scenario that was planned.
        result: Its validated result.
        world: The collision world the plan was made in (robot, cabin, payload).
    """
    q = result.profile.joints
    idx = np.unique(np.concatenate([np.arange(0, len(q), max(1, len(q) // 200)), [len(q) - 1]]))
    clearance = world.clearance_profile(q[idx]) if sc.cabin is not None else None
    return profile_png(
        result.profile,
        sc.robot,
        result.profile.t[idx],
        clearance,
        sc.options.clearance_m,
        title=f"{sc.spec.name}: {result.profile.duration_s:.2f} s",
        deflection=result.deflection,
    )
