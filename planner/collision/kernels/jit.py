"""The numba dispatchers of the collision kernels' entries, in one namespace (imports numba).

:mod:`.entries` calls these when no ahead-of-time build is used, and the build compiles them
(:data:`.entries.EXTENSION`); their names are the entry names.
"""

from __future__ import annotations

from planner.collision.kernels.along import bounds_at, cover_walk
from planner.collision.kernels.bounds import cover_centres_batch, cover_extents
from planner.collision.kernels.distances import pair_touches
from planner.collision.kernels.grid import grid_bounds, grid_marks
from planner.collision.kernels.mesh import (
    box_mesh_distance,
    box_touches_mesh,
    cabin_witness,
    capsule_mesh_distance,
    capsule_touches_mesh,
    hull_mesh_lower,
    hull_shape_lower,
    mesh_tree,
    pair_witness,
)
from planner.collision.kernels.obstacles import obstacle_bounds, obstacle_coarse_batch, obstacle_fine_batch
from planner.collision.kernels.offsets import (
    hull_deviation,
    pair_vertices,
    path_vertices,
    task_offsets,
)
from planner.collision.kernels.spread import between_bound, cumulative_bound, propagate
from planner.collision.kernels.state import axis_sweep, packed_check, packed_poses, packed_state, packed_valid
from planner.collision.kernels.walk import (
    end_ratio,
    first_inadmissible,
    motion_walk,
    run_extent,
    segment_reach,
)

__all__ = [
    "axis_sweep",
    "between_bound",
    "bounds_at",
    "box_mesh_distance",
    "box_touches_mesh",
    "cabin_witness",
    "capsule_mesh_distance",
    "capsule_touches_mesh",
    "cover_centres_batch",
    "cover_extents",
    "cover_walk",
    "cumulative_bound",
    "end_ratio",
    "first_inadmissible",
    "grid_bounds",
    "grid_marks",
    "mesh_tree",
    "hull_deviation",
    "hull_mesh_lower",
    "hull_shape_lower",
    "motion_walk",
    "obstacle_bounds",
    "obstacle_coarse_batch",
    "obstacle_fine_batch",
    "packed_check",
    "packed_poses",
    "packed_state",
    "packed_valid",
    "pair_touches",
    "pair_vertices",
    "pair_witness",
    "path_vertices",
    "propagate",
    "run_extent",
    "segment_reach",
    "task_offsets",
]
