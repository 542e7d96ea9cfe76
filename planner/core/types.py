"""Array aliases shared by every module (each docstring gives the shape, e.g. (N samples, dof))."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: A float64 array.
Array = NDArray[np.float64]
#: An int64 array.
IntArray = NDArray[np.int64]
#: A boolean array.
BoolArray = NDArray[np.bool_]
