"""The one way a figure becomes PNG bytes (matplotlib's Agg backend, no screen, no file)."""

from __future__ import annotations

import io
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

#: Resolution of every PNG the planner writes.
DPI = 90


def png_bytes(fig: Any, title: str | None = None) -> bytes:
    """The figure (with its title, laid out) as PNG bytes; the figure is closed."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    plt.close(fig)
    return buf.getvalue()
