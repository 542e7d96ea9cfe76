"""Collision benchmarks on every reference cabin (issue targets in brackets).

* one full validity check (limits + robot and payload vs cabin + self), median    [<= 50 us]
* certified motion check of a typical planner edge (joint step of norm 0.15)      [<= 1 ms]
* exact minimum-distance queries (reports and clearance profiles)

Each figure is also measured, in the same run and on the same inputs, on the reference route
(:class:`~planner.collision.oracle.ReferenceWorld`: CasADi poses, the motion walk in Python with the
original always-probe policy), so the speed-up is not blurred by the load of a shared machine.

Configurations: random admissible joints along the whole rail, payload 0.45 x 0.35 x 0.50 m held 0.30 m
along the tool z axis; validity is timed on valid and invalid states alike (both occur in planning).
Run: ``python -m bench.collision``.
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Callable, Iterable
from functools import partial
from typing import Any

import numpy as np

from planner.collision.bodies import PayloadGeometry
from planner.collision.oracle import ReferenceWorld
from planner.collision.world import CollisionWorld
from planner.meshes import REFERENCE_DIR
from planner.meshio import load_mesh
from planner.redundancy.ik import random_admissible_joints
from planner.robots.cabin8 import Cabin8

MESHES = REFERENCE_DIR


def _motion(world: Any, edge: tuple[Any, Any]) -> object:
    return world.check_motion(*edge)


def timed(fn: Callable[[Any], object], items: Iterable[Any]) -> list[float]:
    out: list[float] = []
    for it in items:
        t0 = time.perf_counter()
        fn(it)
        out.append((time.perf_counter() - t0) * 1e6)
    return out


def summary(us: list[float]) -> str:
    return f"median {statistics.median(us):8.1f} us  p95 {np.percentile(us, 95):8.1f} us"


def main() -> None:
    robot = Cabin8()
    rng = np.random.default_rng(0)
    qs = random_admissible_joints(robot, rng, 400, max_tries=4000)
    qs[:, 0] = rng.uniform(0.2, 5.8, len(qs))
    grasp = np.eye(4)
    grasp[2, 3] = 0.30
    payload = PayloadGeometry((0.45, 0.35, 0.50), T_tool_payload=grasp, mass=100.0)
    manifest = json.loads((MESHES / "cabins.json").read_text())
    print(f"{len(qs)} random admissible configurations along the rail; payload box 0.45 x 0.35 x 0.50 m\n")
    for cabin in manifest["cabins"]:
        t0 = time.perf_counter()
        mesh = load_mesh(MESHES / f"{cabin['name']}.stl", units="m")
        world = CollisionWorld(robot, mesh, payload)
        build_s = time.perf_counter() - t0
        ref = ReferenceWorld(robot, mesh, payload)
        valid = [world.is_valid(q) for q in qs]  # warm-up: compiled kernels, FCL objects, caches
        timed(world.is_valid, qs)
        t_valid = timed(world.is_valid, qs)
        timed(ref.is_valid, qs)
        t_valid_ref = timed(ref.is_valid, qs)
        per_s = 1e6 / statistics.median(t_valid)
        starts = [q for q, v in zip(qs, valid, strict=True) if v]
        edges = []
        for q in starts:
            step = rng.normal(size=8)
            step *= 0.15 / np.linalg.norm(step)
            edges.append((q, q + step))
        motion, motion_ref = partial(_motion, world), partial(_motion, ref)
        timed(motion, edges[:20])
        t_edge = timed(motion, edges[:150])
        timed(motion_ref, edges[:20])
        t_edge_ref = timed(motion_ref, edges[:150])
        reports = [world.check_motion(*e) for e in edges[:150]]
        certified = sum(r.valid for r in reports)
        certified_ref = sum(ref.check_motion(*e).valid for e in edges[:150])
        states = statistics.mean(r.states_checked for r in reports)
        queries = statistics.mean(r.fcl_queries for r in reports)
        t_dist = timed(world.min_distance, starts[:60])
        print(
            f"{cabin['name']} ({len(mesh.faces)} faces, world built in {build_s:.2f} s, "
            f"{sum(valid)}/{len(qs)} states valid)"
        )
        print(f"  validity check         {summary(t_valid)}  ({per_s:,.0f} checks/s)  [<= 50 us]")
        print(f"    reference route      {summary(t_valid_ref)}")
        print(
            f"  motion check, edge     {summary(t_edge)}  ({certified}/{len(edges[:150])} certified, "
            f"{states:.1f} states, {queries:.1f} FCL queries per edge)  [<= 1 ms]"
        )
        print(
            f"    reference route      {summary(t_edge_ref)}  ({certified_ref}/{len(edges[:150])} certified)"
        )
        print(
            f"  min distance (exact)   {summary(t_dist)}  ({1e6 / statistics.median(t_dist):,.0f} queries/s)"
        )


if __name__ == "__main__":
    main()
