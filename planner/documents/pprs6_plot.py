"""Plots of the pprs6 platform: workspace views (paper Fig. 5) and drive displacements (Fig. 7).

Kept at the edge (matplotlib, Agg): nothing in the kinematics or timing core imports this module.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from planner.core.types import Array
from planner.documents.figures import png_bytes
from planner.kinematics.workspace import Workspace  # noqa: E402


def workspace_png(ws: Workspace, title: str = "") -> bytes:
    """PNG bytes of three orthogonal views (X-Y, X-Z, Y-Z) of the admissible set, in mm."""
    ax_mm = [1e3 * a for a in ws.axes]
    views = ((0, 1, 2, "X", "Y"), (0, 2, 1, "X", "Z"), (1, 2, 0, "Y", "Z"))
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.4))
    for ax, (i, j, k, a, b) in zip(axes, views, strict=True):
        proj = ws.inside.any(axis=k)
        half = 0.5e3 * ws.step_m
        extent = (ax_mm[i][0] - half, ax_mm[i][-1] + half, ax_mm[j][0] - half, ax_mm[j][-1] + half)
        ax.imshow(proj.T, origin="lower", extent=extent, cmap="Blues", vmin=0, vmax=1.6, aspect="equal")
        ax.plot(1e3 * ws.boundary[:, i], 1e3 * ws.boundary[:, j], ",", color="navy", alpha=0.4)
        if ws.n_inside:
            (lo_i, hi_i), (lo_j, hi_j) = 1e3 * ws.extents_m[i], 1e3 * ws.extents_m[j]
        else:  # nothing reachable at this orientation: show the searched box, empty
            (lo_i, hi_i), (lo_j, hi_j) = extent[:2], extent[2:]
            ax.text(0.5, 0.5, "no reachable position", transform=ax.transAxes, ha="center", va="center")
        ax.set_xlim(lo_i - 10, hi_i + 10)
        ax.set_ylim(lo_j - 10, hi_j + 10)
        ax.set_xlabel(f"{a} [mm]")
        ax.set_ylabel(f"{b} [mm]")
        ax.set_title(f"{a}-{b} view")
        ax.grid(alpha=0.3)
    return png_bytes(fig, title or f"workspace: {1e6 * ws.volume_m3:.0f} cm^3")


def drives_png(t: Array, position: Array, drive_names: tuple[str, ...], title: str = "") -> bytes:
    """PNG bytes of the drive displacements against time: (a) beta [deg], (b) w1, w2, s1-s3 [mm].

    Args:
        t: (N,) sample times [s].
        position: (N, 6) drive positions in the order of ``drive_names`` [m, rad].
        drive_names: Drive names; "beta" is the revolute.
        title: Figure title.
    """
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.2))
    for k, name in enumerate(drive_names):
        if name == "beta":
            a1.plot(t, np.degrees(position[:, k]), color="C3", label=name)
        else:
            a2.plot(t, 1e3 * position[:, k], label=name)
    a1.set_title("(a) chain-3 revolute angle beta")
    a1.set_xlabel("t [s]")
    a1.set_ylabel("beta [deg]")
    a2.set_title("(b) drive displacements")
    a2.set_xlabel("t [s]")
    a2.set_ylabel("displacement [mm]")
    a2.legend(loc="best", fontsize=8)
    for ax in (a1, a2):
        ax.grid(alpha=0.3)
    return png_bytes(fig, title)
