"""Seeded generators of cabins, planning scenarios (and, in :mod:`.cycles`, cycles and campaigns).

Each case is drawn from its own generator ``numpy.random.default_rng([seed, index])`` (a family other than
``mixed`` adds its tag as a third word), so case ``i`` of a seed is the same whatever the count, and the
same seed gives the same bytes. A case is built in this order (:mod:`planner.generate.cases.draw`):

1. **Payload**: a box of several sizes, 20-120 kg (20-110 kg in the families), grasped at an offset along
   and across the tool axis.
2. **Goal** (the robot's reachable workspace decides where things go, never the planner):

   * ``bay-side``: a rack bay in the +x wall, insertion along +x (the arm cannot point to -x: theta3 is
     within +-105 deg);
   * ``bay-end-far`` / ``bay-end-near``: a bay recessed into the far (+z) or near (-z) end wall, insertion
     along the rail;
   * ``shelf``: a pose goal without approach, the payload set down just above a shelf plate;
   * ``drive``: a drive goal (a second holdable configuration elsewhere along the rail).

   For a pose goal, an axis-aligned payload orientation is chosen and the payload position is sampled
   until the redundant family of the inverse kinematics (:func:`planner.redundancy.ik.family_candidates`)
   has an exact, admissible solution at the goal and at the pre-insertion pose (approach distance: the
   payload fully out of the bay plus 30-80 mm). The bay is then built *around* that payload pose with the
   drawn free space per side (12-40 mm to each side wall, top, bottom and back panel).
3. **Cabin**: a shell (round, 2.4-3.0 m inner diameter; octagonal or box-section in their families) with
   the floor deck of the reference cabins, ring frames, stringers (their family), overhead ducts, wall
   brackets and a bulkhead hatch between start and goal whose stepped opening is sized for the robot's
   tucked posture with this payload (widened until a straight rail motion in that posture is certified
   clear).
4. **Checks** with the project's own models: the goal (one exact IK solution) keeps the requested
   clearance (:class:`~planner.collision.world.CollisionWorld`) and is holdable
   (:class:`~planner.plan.goals.StaticForceCheck`); the start keeps the requested clearance + 20 mm and
   is holdable; a drive goal alike. A draw that fails is redrawn (the case's generator moves on).
5. **Files**: the cabin mesh in one of STL/OBJ/PLY/GLB, in m or mm, authored in a frame shifted along
   and rotated about the cabin axis (the scenario's ``cabin.pose`` maps it back), and an ordinary scenario
   dict a user can run with ``cabinplan plan``.

Rooms: :mod:`.options` (ranges, options, the case), :mod:`.families` (the registry of families),
:mod:`.sections` and :mod:`.cabins` (cabin geometry), :mod:`.reach` (what the robot reaches),
:mod:`.cases` (one module per goal kind, clutter, hatch, the draw), :mod:`.files` (mesh and scenario
files). Everything is pure (numpy in, bytes and dicts out) except :func:`write_case` and
:func:`write_manifest` at the edge.

Frame (as in ``planner/meshes/README.md``): z along the cabin axis and the rail, y up, x lateral; SI units.
"""

from __future__ import annotations

from planner.generate.cabins import CabinLayout, RingFrame, Stringer, cabin_mesh, ring_frame
from planner.generate.cases import generate_case, generate_cases
from planner.generate.families import FAMILIES, NEW_FAMILIES, Family
from planner.generate.files import mesh_bytes, scenario_yaml, write_case, write_manifest
from planner.generate.options import (
    GOAL_KINDS,
    MESH_FORMATS,
    START_EXTRA_M,
    GeneratedCase,
    GeneratorOptions,
)
from planner.generate.reach import exact_solutions, payload_rotation

__all__ = [
    "FAMILIES",
    "GOAL_KINDS",
    "MESH_FORMATS",
    "NEW_FAMILIES",
    "START_EXTRA_M",
    "CabinLayout",
    "Family",
    "GeneratedCase",
    "GeneratorOptions",
    "RingFrame",
    "Stringer",
    "cabin_mesh",
    "exact_solutions",
    "generate_case",
    "generate_cases",
    "mesh_bytes",
    "payload_rotation",
    "ring_frame",
    "scenario_yaml",
    "write_case",
    "write_manifest",
]
