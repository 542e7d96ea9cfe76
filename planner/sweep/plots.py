"""Summary figures of a sweep (matplotlib, Agg): feasibility map, duration histogram, reasons chart.

Pictures only; the numbers come from the result rows of :mod:`planner.sweep.results`.
"""

from __future__ import annotations

import io
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

#: Outcome colours: succeeded green, each refusal reason its own colour (stable by first appearance).
_SUCCESS = "#2ca02c"
_PALETTE = ("#d62728", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#1f77b4")


def _outcome(row: dict[str, Any]) -> str:
    return "succeeded" if row.get("status") == "succeeded" else str(row.get("reason") or "failed")


def _colours(rows: list[dict[str, Any]]) -> dict[str, str]:
    out = {"succeeded": _SUCCESS}
    for row in rows:
        key = _outcome(row)
        if key not in out:
            out[key] = _PALETTE[(len(out) - 1) % len(_PALETTE)]
    return out


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def _figure(size: tuple[float, float]) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=size, layout="constrained")


def feasibility_map_png(rows: list[dict[str, Any]]) -> bytes:
    """Goal positions along the cabin (z) and in height (y), each plan a marker coloured by its outcome.

    Plans that share a goal position (other axes varied) sit side by side around it, so each stays
    visible; bays are labelled.
    """
    fig = _figure((9.0, 4.2))
    ax = fig.add_subplot()
    colours = _colours(rows)
    at: dict[tuple[float, float], list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        if row.get("goal_z_m") is not None and row.get("goal_y_m") is not None:
            at[(float(row["goal_z_m"]), float(row["goal_y_m"]))].append(row)
    zs = sorted({z for z, _ in at})
    spacing = min((b - a for a, b in zip(zs, zs[1:], strict=False)), default=0.5)
    seen: set[str] = set()
    for (z, y), group in at.items():
        width = 0.6 * spacing
        for k, row in enumerate(group):
            dz = 0.0 if len(group) == 1 else width * (k / (len(group) - 1) - 0.5)
            key = _outcome(row)
            ax.scatter(
                [z + dz],
                [y],
                s=60,
                color=colours[key],
                edgecolor="black",
                linewidth=0.4,
                label=key if key not in seen else None,
            )
            seen.add(key)
        bay = group[0].get("bay")
        if bay:
            ax.annotate(str(bay), (z, y), textcoords="offset points", xytext=(0, 10), ha="center", fontsize=8)
    if not at:
        ax.text(0.5, 0.5, "no pose goals in this sweep", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("goal z along the cabin [m]")
    ax.set_ylabel("goal y (height) [m]")
    ax.set_title("Feasibility map: outcome of each plan at its goal position")
    ax.grid(True, alpha=0.3)
    if seen:
        ax.legend(loc="best", fontsize=8)
    return _png(fig)


def duration_histogram_png(rows: list[dict[str, Any]]) -> bytes:
    """Histogram of the trajectory durations of the plans that succeeded."""
    fig = _figure((6.0, 3.8))
    ax = fig.add_subplot()
    durations = [
        float(r["duration_s"]) for r in rows if r.get("status") == "succeeded" and r.get("duration_s")
    ]
    if durations:
        ax.hist(durations, bins=min(30, max(5, len(durations) // 2)), color=_SUCCESS, edgecolor="black")
    else:
        ax.text(0.5, 0.5, "no plan succeeded", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("trajectory duration [s]")
    ax.set_ylabel("plans")
    ax.set_title(f"Durations of the {len(durations)} feasible plans")
    ax.grid(True, alpha=0.3)
    return _png(fig)


def reasons_png(rows: list[dict[str, Any]]) -> bytes:
    """Bar chart of the outcomes: succeeded and every refusal reason, with counts."""
    fig = _figure((7.0, 3.8))
    ax = fig.add_subplot()
    colours = _colours(rows)
    counts = Counter(_outcome(r) for r in rows)
    names = sorted(counts, key=lambda k: (k != "succeeded", -counts[k], k))
    bars = ax.barh(names, [counts[n] for n in names], color=[colours[n] for n in names], edgecolor="black")
    ax.bar_label(bars, padding=3)
    ax.invert_yaxis()
    ax.set_xlabel("plans")
    ax.set_title(f"Outcomes of {len(rows)} plans")
    return _png(fig)


#: File name -> figure function, as written by :func:`write_plots`.
PLOTS = {
    "feasibility_map.png": feasibility_map_png,
    "durations.png": duration_histogram_png,
    "reasons.png": reasons_png,
}


def write_plots(out_dir: Path, rows: list[dict[str, Any]]) -> list[Path]:
    """Write every summary plot into ``out_dir``; the paths written."""
    paths = []
    for name, fn in PLOTS.items():
        path = Path(out_dir) / name
        path.write_bytes(fn(rows))
        paths.append(path)
    return paths


__all__ = ["PLOTS", "duration_histogram_png", "feasibility_map_png", "reasons_png", "write_plots"]
