"""The generator's families (planner.generate.families): their geometry, and one case of each planned.

Geometry is checked against its own definition, independently of the mesh code: every outline of a
section lies at its offset from the inner surface, the half-width at a height is on the wall, the
carriage keeps its margin along the whole rail, ring frames and stringers stay where the family says. One
case per family (3 m rail: a short section) is planned with the default options and its profile document,
after a JSON round trip, re-checked by the independent gate route (:func:`planner.check_profile`: world
and requirements rebuilt from the scenario file).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import planner
from planner.documents.output import result_document
from planner.generate import FAMILIES, NEW_FAMILIES, GeneratorOptions, generate_case, write_case
from planner.generate.cases.common import CARRIAGE_CORNERS
from planner.generate.sections import RoundSection, box_section, octagon, shell_over
from planner.meshes.generate import Shell
from planner.meshio.load import load_mesh
from planner.plan.pipeline import plan_scenario as plan
from planner.scenario import load_scenario

OPTIONS = {name: GeneratorOptions(rail_length_m=3.0, family=name) for name in NEW_FAMILIES}
SECTIONS = [
    RoundSection(shell_over(Shell(inner_radius_m=1.3), -0.5, 3.5)),
    octagon(shell_over(Shell(), -0.5, 3.5), 1.2),
    octagon(shell_over(Shell(), -0.5, 3.5), 1.5),
    box_section(shell_over(Shell(), -0.5, 3.5), 1.15, -0.45, 1.8, 0.4),
    box_section(shell_over(Shell(), -0.5, 3.5), 1.45, -0.6, 2.15, 0.2),
]


@pytest.mark.parametrize("section", SECTIONS, ids=lambda s: f"{s.kind}-{s.shell.inner_radius_m}")
@pytest.mark.parametrize("offset", [-0.1, 0.0, 0.02, 0.04])
def test_every_outline_lies_at_its_offset_from_the_inner_surface(section, offset: float) -> None:
    pts = section.outline(offset)
    assert np.max(np.abs(section.wall_distance(pts) + offset)) <= 1e-9
    rim = section.rim(offset)
    assert np.max(np.abs(section.wall_distance(rim) + offset)) <= 1e-9
    # counter-clockwise: the shoelace area is positive
    x, y = pts[:, 0], pts[:, 1]
    assert np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0


@pytest.mark.parametrize("section", SECTIONS, ids=lambda s: f"{s.kind}-{s.shell.inner_radius_m}")
def test_half_width_is_on_the_wall_and_rays_meet_it(section) -> None:
    for y in np.linspace(-0.3, 1.6, 12):
        x = section.half_width_at(float(y))
        assert abs(section.wall_distance(np.array([[x, y], [-x, y]]))).max() <= 1e-9
    for angle in np.linspace(-math.pi, math.pi, 17):
        p, n = section.wall_point(float(angle))
        assert abs(section.wall_distance(p[None, :])[0]) <= 1e-9
        assert abs(np.linalg.norm(n) - 1.0) <= 1e-12
        # the normal points outwards: a step along it leaves the section
        assert section.wall_distance((p + 0.01 * n)[None, :])[0] < 0
    # the carriage runs the whole rail with more than 80 mm to the wall
    assert section.wall_distance(CARRIAGE_CORNERS).min() > 0.08


@pytest.fixture(scope="module")
def family_cases(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[object, Path]]:
    folder = tmp_path_factory.mktemp("families")
    out = {}
    for name in NEW_FAMILIES:
        case = generate_case(5, 0, OPTIONS[name])
        out[name] = (case, write_case(case, folder))
    return out


def test_families_are_drawn_apart_and_reproducibly(family_cases, tmp_path: Path) -> None:
    names = {c.name for c, _ in family_cases.values()}
    assert len(names) == len(NEW_FAMILIES)
    again = generate_case(5, 0, OPTIONS["octagonal"])
    case, path = family_cases["octagonal"]
    assert again.mesh_bytes == case.mesh_bytes
    assert write_case(again, tmp_path).read_bytes() == path.read_bytes()
    with pytest.raises(ValueError, match="family"):
        GeneratorOptions(family="spherical")


@pytest.mark.parametrize("name", NEW_FAMILIES)
def test_each_family_draws_what_it_promises(name: str, family_cases) -> None:
    case, path = family_cases[name]
    family, meta, layout = FAMILIES[name], case.meta, case.layout
    assert meta["family"] == name and meta["goal"] in family.goal_kinds
    assert family.mass_range_kg[0] <= meta["mass_kg"] <= family.mass_range_kg[1]
    assert layout.section.kind == family.section
    if family.ring_probability == 1.0:
        assert len(layout.rings) >= 2
    spacing = np.diff([r.z_m for r in layout.rings])
    assert np.all(spacing >= family.ring_spacing_m[0] - 1e-3)
    for r in layout.rings:  # never deeper than leaves the carriage 30 mm
        assert r.depth_m <= layout.section.wall_distance(CARRIAGE_CORNERS).min() - 0.03 + 1e-9
    if family.stringers is not None:
        assert 0 < meta["stringers"] < family.stringers[1]  # those above the carriage of those drawn
        for s in layout.stringers:
            assert layout.section.wall_point(s.angle_rad)[0][1] >= 0.12
    # drawn within the family's range; one that would enter the goal's keep-out is left out
    assert len(layout.ducts) < family.ducts[1] and len(layout.brackets) < family.brackets[1]
    for d in layout.ducts:
        assert layout.section.inside(np.array([[d.x_m, d.y_m]]), d.radius_m, 0.0295)
    # the file loads to the cabin in its units and frame
    sc = load_scenario(path)
    mesh = load_mesh(case.mesh_bytes, units=meta["units"], name=case.mesh_name, pose=case.T_base_cabin)
    assert np.max(np.abs(sc.cabin.bounds_m - mesh.bounds_m)) <= 1e-9


#: 1-3 s each on a quiet machine with the cabin's first build (6-9 s at load 8): marked slow, still run.
@pytest.mark.slow
@pytest.mark.parametrize("name", NEW_FAMILIES)
def test_one_case_of_each_family_plans_and_passes_the_independent_check(name: str, family_cases) -> None:
    _, path = family_cases[name]
    sc = load_scenario(path)
    res = plan(sc)
    doc = json.loads(json.dumps(result_document(sc, res)))
    report = planner.check_profile(load_scenario(path), doc)
    assert report.passed, report.summary()
    u = np.asarray(doc["position"])
    assert np.max(np.abs(u[0] - sc.start_u)) <= 1e-9
    assert np.all(np.asarray(doc["velocity"])[[0, -1]] == 0.0)
    if sc.goal_u is not None:
        assert np.max(np.abs(u[-1] - sc.goal_u)) <= 1e-6


def test_the_cli_names_an_unknown_family_in_one_line(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from planner.cli import app

    result = CliRunner().invoke(
        app, ["generate", "-o", str(tmp_path), "--count", "1", "--family", "spherical"]
    )
    assert result.exit_code == 2
    assert "family: must be one of mixed, ring-frame" in result.stderr and "'spherical'" in result.stderr
    assert not list(tmp_path.iterdir())
