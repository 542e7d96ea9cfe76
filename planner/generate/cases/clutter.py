"""What stands in the cabin besides the goal: ring frames, stringers, ducts and wall brackets.

Nothing enters the goal's keep-out boxes (the bay and its approach corridor, the space above a shelf): a
ring frame or stringer whose z range crosses one must stay shallower than the box is deep inside the wall;
a duct or bracket that would enter one is left out (its draw consumed).
"""

from __future__ import annotations

import math

import numpy as np

from planner.core.types import Array
from planner.generate.cabins import RingFrame, Stringer, bracket_bounds, stringer_box
from planner.generate.cases.common import Draw, clutter_ok, keep_clear, ring_depth_max
from planner.generate.families import Family
from planner.meshes.generate import Bracket, Duct

#: Stringers stand where the wall is at least this high [m] (above the carriage, which is at y <= 0).
STRINGER_MIN_Y_M = 0.12


def draw_rings(d: Draw, family: Family, keep_out: list[tuple[Array, Array]]) -> list[RingFrame]:
    """Ring frames 30-70 mm thick, 30-100 mm deep (never deeper than leaves the carriage 30 mm)."""
    rng, section = d.rng, d.section
    shell = section.shell
    rings: list[RingFrame] = []
    if rng.uniform() >= family.ring_probability:
        return rings
    depth_max = ring_depth_max(section)
    if depth_max <= 0.03:
        return rings
    spacing = rng.uniform(*family.ring_spacing_m)
    depth = float(np.round(rng.uniform(0.03, min(0.10, depth_max)), 3))
    thick = float(np.round(rng.uniform(0.03, 0.07), 3))
    z = shell.z_min_m + rng.uniform(0.3, 0.3 + spacing)
    while z < shell.z_max_m - 0.3:
        lo = np.array([-2.0, -1.0, z - 0.02])
        hi = np.array([2.0, 3.0, z + thick + 0.02])
        if keep_clear(section, lo, hi, keep_out, depth):
            rings.append(RingFrame(float(np.round(z, 3)), thick, depth))
        z += spacing
    return rings


def draw_ducts(d: Draw, family: Family, keep_out: list[tuple[Array, Array]]) -> list[Duct]:
    """Ducts of 50-110 mm radius along the whole section, 40-100 mm from the upper wall."""
    rng, section = d.rng, d.section
    shell = section.shell
    ducts: list[Duct] = []
    for _ in range(int(rng.integers(*family.ducts))):
        radius = float(np.round(rng.uniform(0.05, 0.11), 3))
        angle = math.pi / 2 + rng.uniform(-1.0, 1.0)
        x, y = section.duct_centre(angle, radius, rng.uniform(0.04, 0.10))
        z0, z1 = shell.z_min_m + 0.04, shell.z_max_m - 0.04
        cand = Duct(float(np.round(x, 3)), float(np.round(y, 3)), radius, z0, z1)
        lo, hi = np.array([x - radius, y - radius, z0]), np.array([x + radius, y + radius, z1])
        if clutter_ok(lo, hi, keep_out) and section.inside(np.array([[x, y]]), radius, 0.03):
            ducts.append(cand)
    return ducts


def draw_brackets(d: Draw, family: Family, keep_out: list[tuple[Array, Array]]) -> list[Bracket]:
    """Wall brackets protruding 80-220 mm, 60-120 mm high, 120-350 mm long, at 0.3-1.5 m height."""
    rng, section = d.rng, d.section
    shell = section.shell
    brackets: list[Bracket] = []
    for _ in range(int(rng.integers(*family.brackets))):
        b = Bracket(
            side=int(rng.choice([-1, 1])),
            y_center_m=float(np.round(rng.uniform(0.3, 1.5), 3)),
            z_center_m=float(np.round(rng.uniform(shell.z_min_m + 0.3, shell.z_max_m - 0.3), 3)),
            protrusion_m=float(np.round(rng.uniform(0.08, 0.22), 3)),
            height_m=float(np.round(rng.uniform(0.06, 0.12), 3)),
            length_m=float(np.round(rng.uniform(0.12, 0.35), 3)),
        )
        b_lo, b_hi = bracket_bounds(section, b)
        if clutter_ok(np.array(b_lo), np.array(b_hi), keep_out):
            brackets.append(b)
    return brackets


def _free_spans(
    z0: float, z1: float, lo: Array, hi: Array, keep_out: list[tuple[Array, Array]]
) -> list[tuple[float, float]]:
    """Parts of [z0, z1] (each >= 0.1 m) where a stringer's box (lo, hi) keeps 20 mm off the keep-outs."""
    spans = [(z0, z1)]
    for k_lo, k_hi in keep_out:
        if np.any(hi[:2] <= k_lo[:2] - 0.02) or np.any(lo[:2] >= k_hi[:2] + 0.02):
            continue
        cut_lo, cut_hi = float(k_lo[2]) - 0.02, float(k_hi[2]) + 0.02
        spans = [
            piece
            for a, b in spans
            for piece in ((a, min(b, cut_lo)), (max(a, cut_hi), b))
            if piece[1] - piece[0] >= 0.1
        ]
    return spans


def draw_stringers(d: Draw, family: Family, keep_out: list[tuple[Array, Array]]) -> list[Stringer]:
    """Stringers 20-40 mm wide, 20-45 mm deep, evenly spread over the wall above the carriage.

    Each runs the section's length between the end walls, interrupted where it would enter a keep-out.
    """
    if family.stringers is None:
        return []
    rng, section = d.rng, d.section
    shell = section.shell
    count = int(rng.integers(*family.stringers))
    width = float(np.round(rng.uniform(0.02, 0.04), 3))
    height = float(np.round(rng.uniform(0.02, 0.045), 3))
    phase = rng.uniform(0.0, 1.0)
    out: list[Stringer] = []
    for k in range(count):
        angle = float(np.round(-0.45 + (k + phase) * (math.pi + 0.9) / count, 4))
        if section.wall_point(angle)[0][1] < STRINGER_MIN_Y_M:
            continue
        probe = Stringer(angle, width, height, shell.z_min_m + shell.wall_m, shell.z_max_m - shell.wall_m)
        lo, hi = stringer_box(section, probe)
        for z0, z1 in _free_spans(probe.z_min_m, probe.z_max_m, lo, hi, keep_out):
            out.append(Stringer(angle, width, height, float(np.round(z0, 4)), float(np.round(z1, 4))))
    return out


__all__ = ["STRINGER_MIN_Y_M", "draw_brackets", "draw_ducts", "draw_rings", "draw_stringers"]
