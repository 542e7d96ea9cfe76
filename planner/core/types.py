"""Array aliases shared by the whole planner: one name per element type.

Shapes are written in each function's docstring ("(N, 8)", "(B, 13)"); the aliases only fix the dtype.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: Float64 arrays: joints [m or rad], positions [m], bounds [m].
Array = NDArray[np.float64]
#: Int64 arrays: indices and counts.
IntArray = NDArray[np.int64]
#: Boolean masks.
BoolArray = NDArray[np.bool_]

__all__ = ["Array", "BoolArray", "IntArray"]
