"""``python -m planner.collision.kernels.build``: the ahead-of-time build of the collision kernels.

Builds :data:`planner.collision.kernels.entries.EXTENSION` into the cache folder and prints its path
(``make`` runs it after installing; a plan that finds no build runs it before its clock starts).
"""

from __future__ import annotations

from planner.collision.kernels.entries import EXTENSION
from planner.core import aot

if __name__ == "__main__":
    aot.main(EXTENSION)
