"""Expansion of a sweep into its plans: each an ordinary, validated scenario that can be re-run alone.

The axes of :class:`~planner.sweep.spec.Axes` are combined as a cross product in a fixed order (goal,
start, payload mass, payload box, grasp, clearance, seed; the last varies fastest), or the explicit
``plans`` are taken as listed. Each combination changes the base scenario's fields:

* a bay: goal pose at the bay's centre (``center_m`` of the manifest), in the bay orientation, with a
  straight insertion along the bay's ``insertion_axis``;
* a goal pose or grid point: goal pose (the base goal's orientation when none is given), keeping the
  base goal's approach;
* payload mass / box / grasp, start posture, ``options.clearance_m``, ``options.seed``.

A plan's scenario name is the sweep name and the first 12 hex digits of the SHA-256 of its content, so
the name (and the scenario hash that keys the results) depends only on what is planned, not on where the
plan sits in the list: reordering or extending the axes keeps the hashes of the plans already done.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from planner.core.exceptions import InvalidInput
from planner.core.schemas import Pose
from planner.meshes import reference_cabin_path, reference_manifest
from planner.scenario import Scenario, load_scenario_file, scenario_from_dict, scenario_hash
from planner.sweep.spec import MAX_PLANS, PlanPoint, StartPosture, SweepSpec

_LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class SweepPlan:
    """One plan of a sweep.

    Attributes:
        index: Position in the expanded list (0-based).
        scenario: The validated scenario (mesh paths absolute when the sweep came from a file).
        sha256: :func:`~planner.scenario.scenario_hash` of ``scenario``: the key of its result row.
        labels: What the axes set, for the result table: ``bay``, ``start``, ``grasp`` (names or None).
    """

    index: int
    scenario: Scenario
    sha256: str
    labels: dict[str, str | None] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The scenario name."""
        return self.scenario.name


@dataclass(frozen=True)
class _Choice:
    """One value of one axis: its label and the change it makes to the scenario dict."""

    label_key: str | None
    label: str | None
    key: str
    value: Any


def _canonical(data: Any) -> str:
    return json.dumps(data, sort_keys=True, separators=(",", ":"))


def load_base(spec: SweepSpec, spec_dir: Path | None) -> tuple[Scenario, Path | None]:
    """The base scenario and the folder its relative mesh paths refer to."""
    if isinstance(spec.base, str):
        folder = spec_dir if spec_dir is not None else Path.cwd()
        path = Path(spec.base)
        if not path.is_absolute():
            path = folder / path
        try:
            return load_scenario_file(path), path.parent
        except InvalidInput as exc:
            raise InvalidInput(f"base: {exc.message}", **{**dict(exc.details), "field": "base"}) from None
    try:
        return scenario_from_dict(spec.base, source="base"), spec_dir
    except InvalidInput as exc:
        raise InvalidInput(f"base.{exc.message}", field=f"base.{exc.details.get('field')}") from None


def _absolute_meshes(data: dict[str, Any], mesh_dir: Path) -> None:
    """Relative mesh file paths of the scenario dict made absolute (reference cabin names kept)."""
    cabin = data.get("cabin")
    if cabin is not None and reference_cabin_path(cabin["mesh"]) is None:
        cabin["mesh"] = str((mesh_dir / cabin["mesh"]).resolve())
    payload = data.get("payload")
    if payload is not None and payload.get("mesh") is not None:
        payload["mesh"] = str((mesh_dir / payload["mesh"]).resolve())


def _bays(spec: SweepSpec, base: Scenario, spec_dir: Path | None) -> dict[str, dict[str, Any]]:
    """Bay records (``id`` -> manifest entry) of the sweep's cabin."""
    src = spec.bays
    if src.manifest is not None:
        path = Path(src.manifest)
        if not path.is_absolute():
            path = (spec_dir if spec_dir is not None else Path.cwd()) / path
        try:
            manifest = json.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise InvalidInput(
                f"bays.manifest: cannot read {path} ({exc.strerror})", field="bays.manifest"
            ) from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InvalidInput(
                f"bays.manifest: {path.name} is not JSON ({exc})", field="bays.manifest"
            ) from None
    else:
        manifest = reference_manifest()
    cabin = src.cabin
    if cabin is None:
        if base.cabin is None:
            raise InvalidInput(
                "bays.cabin: the base scenario has no cabin; name the cabin", field="bays.cabin"
            )
        cabin = Path(base.cabin.mesh).name
        cabin = cabin[: -len(Path(cabin).suffix)] if Path(cabin).suffix else cabin
    cabins = manifest.get("cabins") if isinstance(manifest, dict) else None
    if not isinstance(cabins, list):
        raise InvalidInput("bays.manifest: no 'cabins' list in the manifest", field="bays.manifest")
    for entry in cabins:
        if isinstance(entry, dict) and entry.get("name") == cabin:
            bays = entry.get("bays") or []
            out: dict[str, dict[str, Any]] = {}
            for bay in bays:
                try:
                    centre = [float(v) for v in bay["center_m"]]
                    axis = [float(v) for v in bay["insertion_axis"]]
                    assert len(centre) == 3 and len(axis) == 3
                except (KeyError, TypeError, ValueError, AssertionError):
                    raise InvalidInput(
                        f"bays.manifest: bay {bay.get('id')!r} of {cabin!r} needs center_m and "
                        "insertion_axis "
                        "(3 numbers each)",
                        field="bays.manifest",
                    ) from None
                out[str(bay["id"])] = {"center_m": centre, "insertion_axis": axis}
            return out
    names = [str(c.get("name")) for c in cabins if isinstance(c, dict)]
    raise InvalidInput(
        f"bays.cabin: {cabin!r} is not a cabin of the manifest ({', '.join(names)})", field="bays.cabin"
    )


def _goal_choices(spec: SweepSpec, base: Scenario, spec_dir: Path | None) -> list[_Choice]:
    axis = spec.axes.goal
    if axis is None:
        return []
    if axis.bays is not None:
        table = _bays(spec, base, spec_dir)
        ids = list(table) if axis.bays == "all" else list(axis.bays)
        return [_bay_choice(spec, base, table, bay, f"axes.goal.bays[{k}]") for k, bay in enumerate(ids)]
    if axis.poses is not None:
        return [_pose_choice(base, p, f"axes.goal.poses[{k}]") for k, p in enumerate(axis.poses)]
    assert axis.grid is not None
    grid = axis.grid
    out = []
    for p in grid.positions():
        pose = (
            Pose(position=p) if grid.orientation is None else Pose(position=p, orientation=grid.orientation)
        )
        out.append(_pose_choice(base, pose, "axes.goal.grid", explicit=grid.orientation is not None))
    return out


def _base_orientation(base: Scenario, where: str) -> dict[str, Any]:
    if base.goal.pose is None:
        raise InvalidInput(
            f"{where}: the base goal is not a pose, so a goal orientation must be given", field=where
        )
    return base.goal.pose.orientation.model_dump(mode="json")


def _pose_choice(base: Scenario, pose: Pose, where: str, explicit: bool | None = None) -> _Choice:
    has_orientation = "orientation" in pose.model_fields_set if explicit is None else explicit
    orientation = (
        pose.orientation.model_dump(mode="json") if has_orientation else _base_orientation(base, where)
    )
    goal: dict[str, Any] = {"pose": {"position": list(pose.position), "orientation": orientation}}
    if base.goal.approach is not None:
        goal["approach"] = base.goal.approach.model_dump(mode="json")
    return _Choice(None, None, "goal", goal)


def _bay_choice(
    spec: SweepSpec, base: Scenario, table: dict[str, dict[str, Any]], bay: str, where: str
) -> _Choice:
    if bay not in table:
        raise InvalidInput(
            f"{where}: no bay {bay!r} in the cabin (bays: {', '.join(table) or 'none'})", field=where
        )
    src = spec.bays
    orientation = (
        src.orientation.model_dump(mode="json")
        if src.orientation is not None
        else _base_orientation(base, where)
    )
    distance = src.approach_distance_m
    if distance is None:
        if base.goal.approach is None:
            raise InvalidInput(
                "bays.approach_distance_m: the base goal has no approach; give the insertion length",
                field="bays.approach_distance_m",
            )
        distance = base.goal.approach.distance
    goal = {
        "pose": {"position": table[bay]["center_m"], "orientation": orientation},
        "approach": {"direction": table[bay]["insertion_axis"], "distance": float(distance)},
    }
    return _Choice("bay", bay, "goal", goal)


def _start_choice(posture: StartPosture) -> _Choice:
    value = posture.model_dump(mode="json", exclude={"name"}, exclude_none=True)
    return _Choice("start", posture.name, "start", value)


def _axis_choices(spec: SweepSpec, base: Scenario, spec_dir: Path | None) -> list[list[_Choice]]:
    ax = spec.axes
    lists: list[list[_Choice]] = []
    goal = _goal_choices(spec, base, spec_dir)
    if goal:
        lists.append(goal)
    if ax.start is not None:
        lists.append([_start_choice(p) for p in ax.start])
    if ax.payload_mass_kg is not None:
        lists.append([_Choice(None, None, "payload.mass", float(m)) for m in ax.payload_mass_kg])
    if ax.payload_box_m is not None:
        lists.append([_Choice(None, None, "payload.box", list(b)) for b in ax.payload_box_m])
    if ax.grasp is not None:
        lists.append(
            [
                _Choice("grasp", f"grasp-{k}", "payload.grasp", g.model_dump(mode="json"))
                for k, g in enumerate(ax.grasp)
            ]
        )
    if ax.clearance_m is not None:
        lists.append([_Choice(None, None, "options.clearance_m", float(c)) for c in ax.clearance_m])
    if ax.seed is not None:
        lists.append([_Choice(None, None, "options.seed", int(s)) for s in ax.seed])
    return lists


def _point_choices(
    spec: SweepSpec, base: Scenario, point: PlanPoint, k: int, table: dict[str, dict[str, Any]] | None
) -> list[_Choice]:
    where = f"plans[{k}]"
    out: list[_Choice] = []
    if point.bay is not None:
        assert table is not None
        out.append(_bay_choice(spec, base, table, point.bay, f"{where}.bay"))
    if point.goal_pose is not None:
        out.append(_pose_choice(base, point.goal_pose, f"{where}.goal_pose"))
    if point.start is not None:
        out.append(_start_choice(point.start))
    if point.payload_mass_kg is not None:
        out.append(_Choice(None, None, "payload.mass", float(point.payload_mass_kg)))
    if point.payload_box_m is not None:
        out.append(_Choice(None, None, "payload.box", list(point.payload_box_m)))
    if point.grasp is not None:
        out.append(_Choice("grasp", f"plans[{k}]", "payload.grasp", point.grasp.model_dump(mode="json")))
    if point.clearance_m is not None:
        out.append(_Choice(None, None, "options.clearance_m", float(point.clearance_m)))
    if point.seed is not None:
        out.append(_Choice(None, None, "options.seed", int(point.seed)))
    return out


def _apply(data: dict[str, Any], choice: _Choice, where: str) -> None:
    head, _, tail = choice.key.partition(".")
    if not tail:
        data[head] = choice.value
        return
    section = data.get(head)
    if section is None:
        raise InvalidInput(
            f"{where}: the base scenario has no {head}, so {choice.key} cannot be varied", field=where
        )
    if choice.key == "payload.box" and section.get("box") is None:
        raise InvalidInput(f"{where}: the base payload is a mesh, not a box", field=where)
    section[tail] = choice.value


def expand_sweep(
    spec: SweepSpec,
    spec_dir: Path | None = None,
    *,
    absolute_meshes: bool = True,
    max_plans: int = MAX_PLANS,
) -> list[SweepPlan]:
    """Every plan of the sweep, each a validated scenario (duplicates dropped, first kept).

    Args:
        spec: The sweep description.
        spec_dir: Folder that ``base``, ``bays.manifest`` and inline mesh paths refer to (the sweep
            file's folder); the current directory if ``None``.
        absolute_meshes: Make relative mesh file paths absolute, so that each plan's scenario file can
            be re-run from anywhere (the HTTP API, whose mesh names are ids, turns this off).
        max_plans: Most plans accepted (the service sets its own, smaller cap).

    Returns:
        The plans in expansion order.

    Raises:
        InvalidInput: a field the axes vary is missing from the base, an unknown bay, more than
            :data:`~planner.sweep.spec.MAX_PLANS` plans, or a combination that is not a valid scenario
            (the message names the plan and the field).
    """
    base, mesh_dir = load_base(spec, spec_dir)
    base_data = base.model_dump(mode="json")
    if absolute_meshes and mesh_dir is not None:
        _absolute_meshes(base_data, mesh_dir)
    combos: list[tuple[str, list[_Choice]]]
    if spec.plans is not None:
        table = _bays(spec, base, spec_dir) if any(p.bay is not None for p in spec.plans) else None
        if len(spec.plans) > max_plans:
            raise InvalidInput(
                f"plans: {len(spec.plans)} plans, more than {max_plans}; split the sweep", field="plans"
            )
        combos = [(f"plans[{k}]", _point_choices(spec, base, p, k, table)) for k, p in enumerate(spec.plans)]
    else:
        lists = _axis_choices(spec, base, spec_dir)
        total = 1
        for choices in lists:
            total *= len(choices)
        if total > max_plans:
            raise InvalidInput(
                f"axes: the cross product has {total} plans, more than {max_plans}; split the sweep",
                field="axes",
                plans=total,
            )
        combos = [(f"plan {k}", list(c)) for k, c in enumerate(itertools.product(*lists))]
    plans: list[SweepPlan] = []
    seen: set[str] = set()
    for where, choices in combos:
        data = json.loads(_canonical(base_data))
        labels: dict[str, str | None] = {"bay": None, "start": None, "grasp": None}
        for choice in choices:
            _apply(data, choice, where)
            if choice.label_key is not None:
                labels[choice.label_key] = choice.label
        data.pop("name", None)
        digest = hashlib.sha256(_canonical(data).encode()).hexdigest()
        data["name"] = f"{spec.name}-{digest[:12]}"
        try:
            scenario = scenario_from_dict(data, source=where)
        except InvalidInput as exc:
            raise InvalidInput(
                f"{where}: not a valid scenario: {exc.message}", **{**dict(exc.details), "field": where}
            ) from None
        sha = scenario_hash(scenario)
        if sha in seen:
            _LOG.info("%s repeats an earlier plan; planned once", where)
            continue
        seen.add(sha)
        plans.append(SweepPlan(len(plans), scenario, sha, labels))
    return plans


__all__ = ["SweepPlan", "expand_sweep", "load_base"]
