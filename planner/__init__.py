"""cabinplan: trajectory planning and redundancy control for cabin assembly robots.

The package is the pure core: robot models, kinematics, dynamics and the planning pipeline. I/O lives in
:mod:`planner.cli` and in the :mod:`api` service.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("cabinplan")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
