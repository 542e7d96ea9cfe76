"""cabinplan: trajectory planning and redundancy control for cabin assembly robots."""

from planner.core.provenance import __version__

__all__ = ["__version__"]
