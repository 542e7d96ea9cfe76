"""STEP import: exact geometry in, the tessellation's deviation bounded, units and assemblies honoured.

The STEP files are written by :mod:`tests.meshio.step_text` in each test (boxes and cylinders as exact
B-rep solids), so every expected number follows from the geometry: a box's corners, a cylinder's radius.
Bad files (truncated, not STEP, empty, self-referencing, too fine) are refused by the named check, and
OpenCASCADE's own crash on a self-referencing file never reaches the calling process.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest

from planner.core.exceptions import InvalidMesh
from planner.meshio import MeshLimits, load_mesh
from planner.meshio import load as mesh_load
from planner.meshio.step import tessellate_step
from tests.meshio.step_text import UNITS, Box, Cylinder, Part, box_cabin_parts, step_text

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(autouse=True)
def _no_caches(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path / "cache"))
    mesh_load.clear_mesh_cache()
    yield
    mesh_load.clear_mesh_cache()


def _box_file(units: str, lo=(0.0, 0.0, 0.0), hi=(1000.0, 200.0, 50.0)) -> bytes:
    return step_text([Part("b", (Box(lo, hi),))], units).encode()


def _refused(check: str, data: bytes, name: str = "part.step", **kw) -> InvalidMesh:
    with pytest.raises(InvalidMesh) as info:
        load_mesh(data, units="m", name=name, **kw)
    err = info.value
    assert err.details["check"] == check, err.message
    assert name in err.message and "\n" not in err.message
    return err


@pytest.mark.parametrize("units", sorted(UNITS))
def test_units_are_read_from_the_file_and_converted_to_metres(units: str) -> None:
    """The same numbers in mm, m and inch give boxes of 100 x 20 x 5 of that unit, in metres."""
    lo, hi = (-1.0, 2.0, 0.5), (99.0, 22.0, 5.5)
    mesh = load_mesh(_box_file(units, lo, hi), units="m", name="box.step")
    scale = UNITS[units]
    np.testing.assert_allclose(mesh.bounds_m, np.array([lo, hi]) * scale, rtol=1e-6, atol=1e-9)
    assert mesh.report.file_units == units and mesh.units == units
    assert mesh.report.n_faces == 12 and mesh.report.is_closed
    assert mesh.report.surface_area_m2 == pytest.approx(2 * (100 * 20 + 20 * 5 + 100 * 5) * scale**2)


def test_declared_units_do_not_override_the_files() -> None:
    """``units`` applies to unitless formats only: a STEP file in mm loads in mm whatever the caller says."""
    a = load_mesh(_box_file("mm"), units="m", name="box.step")
    b = load_mesh(_box_file("mm"), units="mm", name="box.stp")
    np.testing.assert_array_equal(a.vertices, b.vertices)


def _radial_min(mesh, cx: float, cy: float, z0: float, z1: float, n: int = 12) -> float:
    """Smallest distance from the axis over the lateral triangles, sampled on an n-grid per triangle."""
    tri = mesh.vertices[mesh.faces]
    z = tri[:, :, 2]
    cap = (np.abs(z - z0) < 1e-6).all(axis=1) | (np.abs(z - z1) < 1e-6).all(axis=1)  # float32 z
    tri = tri[~cap]
    w = np.array([(i, j, n - i - j) for i in range(n + 1) for j in range(n + 1 - i)], float) / n
    pts = np.einsum("kw,fwc->fkc", w, tri)
    return float(np.hypot(pts[..., 0] - cx, pts[..., 1] - cy).min())


@pytest.mark.parametrize(("units", "tol_m"), [("mm", 1e-3), ("m", 1e-3), ("mm", 1e-4), ("inch", 2e-4)])
def test_tessellation_lies_within_the_tolerance_of_the_exact_cylinder(units: str, tol_m: float) -> None:
    """Vertices on the exact surface; every point of every triangle at most the tolerance inside it.

    The chord of a polygon of n sides cuts r (1 - cos(pi / n)) inside the circle: OpenCASCADE chooses n so
    that this stays within the linear deflection, in whatever unit the file is written.
    """
    s = 1.0 / UNITS[units]
    r_m, z1_m = 0.12, 0.4
    data = step_text([Part("c", (Cylinder(0.0, 0.0, r_m * s, 0.0, z1_m * s),))], units).encode()
    mesh = load_mesh(data, units="m", name="cyl.step", tessellation_tolerance_m=tol_m)
    r_vertex = np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1])
    on_side = r_vertex > 0.5 * r_m
    np.testing.assert_allclose(r_vertex[on_side], r_m, atol=r_m * 2**-23)  # float32 vertices
    inside = r_m - _radial_min(mesh, 0.0, 0.0, 0.0, z1_m)
    assert 0.0 < inside <= mesh.surface_deviation_m
    assert mesh.surface_deviation_m == pytest.approx(tol_m, rel=1e-3)
    # The tolerance is used, not far exceeded: the next polygon (one side fewer) would cut deeper than it
    # unless OpenCASCADE refined for another reason (its angular deflection of 0.5 rad).
    n_sides = np.unique(np.round(np.arctan2(mesh.vertices[on_side, 1], mesh.vertices[on_side, 0]), 9)).size
    assert r_m * (1 - np.cos(np.pi / n_sides)) == pytest.approx(inside, rel=0.05)
    assert r_m * (1 - np.cos(np.pi / (n_sides - 1))) > tol_m or np.pi / n_sides < 0.5


def test_a_finer_tolerance_gives_more_triangles_and_its_own_cache_entry(tmp_path: Path) -> None:
    data = step_text([Part("c", (Cylinder(0.0, 0.0, 100.0, 0.0, 300.0),))], "mm").encode()
    coarse = load_mesh(data, units="m", name="c.step", tessellation_tolerance_m=1e-3)
    fine = load_mesh(data, units="m", name="c.step", tessellation_tolerance_m=1e-5)
    assert fine.report.n_faces > 4 * coarse.report.n_faces
    assert len(list((tmp_path / "cache" / "meshes").glob("*-step-*.npz"))) == 2


def test_assembly_is_flattened_with_its_placements() -> None:
    """Each part stored around its own origin lands where the assembly places it (incl. a rotation)."""
    Rz = ((0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0))  # 90 deg about z: x -> y
    parts = [
        Part("a", (Box((0.0, 0.0, 0.0), (100.0, 20.0, 10.0)),), p=(500.0, 0.0, 0.0)),
        Part("b", (Box((0.0, 0.0, 0.0), (100.0, 20.0, 10.0)),), R=Rz, p=(0.0, 300.0, 40.0)),
    ]
    mesh = load_mesh(step_text(parts, "mm", assembly="asm").encode(), units="m", name="asm.step")
    assert mesh.report.n_parts == 2 and mesh.report.n_faces == 24
    tri = mesh.vertices[mesh.faces]
    centres = tri.mean(axis=(1,))
    first = centres[:, 0] > 0.25  # part a lies at x >= 0.5 m, part b at x <= 0
    np.testing.assert_allclose(tri[first].reshape(-1, 3).min(axis=0), [0.5, 0.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(tri[first].reshape(-1, 3).max(axis=0), [0.6, 0.02, 0.01], atol=1e-7)
    # b rotated: its x extent (0.1 m) now along y, its y extent (0.02 m) along -x.
    np.testing.assert_allclose(tri[~first].reshape(-1, 3).min(axis=0), [-0.02, 0.3, 0.04], atol=1e-7)
    np.testing.assert_allclose(tri[~first].reshape(-1, 3).max(axis=0), [0.0, 0.4, 0.05], atol=1e-7)


def test_the_walkthrough_cabin_assembly_loads_with_its_documented_bounds() -> None:
    mesh = load_mesh(step_text(box_cabin_parts(), "mm", assembly="cabin").encode(), units="m", name="c.step")
    assert mesh.report.n_parts == 7 and mesh.report.format == "step"
    np.testing.assert_allclose(mesh.bounds_m, [[-1.24, -0.2, -0.54], [1.24, 1.84, 6.54]], atol=1e-6)


def test_cached_step_parse_equals_a_fresh_one_and_starts_no_worker(monkeypatch: pytest.MonkeyPatch) -> None:
    data = _box_file("mm")
    first = load_mesh(data, units="m", name="b.step")
    mesh_load.clear_mesh_cache()

    def no_worker(*args, **kwargs):
        raise AssertionError("tessellated again although the parse cache holds the file")

    monkeypatch.setattr(mesh_load, "tessellate_step", no_worker)
    second = load_mesh(data, units="m", name="b.step")
    np.testing.assert_array_equal(first.vertices, second.vertices)
    np.testing.assert_array_equal(first.faces, second.faces)
    assert second.report == first.report and second.sha256 == first.sha256


def _self_referencing() -> bytes:
    text = _box_file("mm").decode()
    number = re.search(r"#(\d+)=ORIENTED_EDGE", text).group(1)  # type: ignore[union-attr]
    text = re.sub(
        rf"#{number}=ORIENTED_EDGE\('',\*,\*,#\d+,", f"#{number}=ORIENTED_EDGE('',*,*,#{number},", text
    )
    return text.encode()


def _cycle() -> bytes:
    """Two instances referring to each other (a loop whose edge refers back to the loop)."""
    text = _box_file("mm").decode()
    loop = re.search(r"#(\d+)=EDGE_LOOP\('',\(#(\d+)", text)
    assert loop is not None
    oe = loop.group(2)
    text = re.sub(
        rf"#{oe}=ORIENTED_EDGE\('',\*,\*,#\d+,", f"#{oe}=ORIENTED_EDGE('',*,*,#{loop.group(1)},", text
    )
    return text.encode()


@pytest.mark.parametrize(
    ("check", "data", "fragment"),
    [
        ("truncated", _box_file("mm")[:-400], "truncated"),
        ("content", b"solid cube\nendsolid cube\n", "ISO-10303-21"),
        ("empty", b"ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\nENDSEC;\nEND-ISO-10303-21;\n", "empty shape"),
        ("self_reference", _self_referencing(), "refers to itself"),
        ("self_reference", _cycle(), "cycle"),
        ("empty", _box_file("mm").replace(b"MANIFOLD_SOLID_BREP", b"MANIFOLD_SOLID_BRAP"), "no triangles"),
        ("parse", _box_file("mm").replace(b"ENDSEC;\nDATA;", b"DATA;"), "OpenCASCADE could not read"),
    ],
    ids=["truncated", "not-step", "empty", "self-reference", "cycle", "unknown-entity", "no-header-end"],
)
def test_bad_step_files_are_refused_by_the_named_check(check: str, data: bytes, fragment: str) -> None:
    err = _refused(check, data)
    assert fragment in err.message


def test_a_crash_of_opencascade_is_a_refusal_of_the_file_not_of_the_process(monkeypatch) -> None:
    """OpenCASCADE overflows its stack on a self-referencing entity (SIGSEGV, measured): only the worker dies.

    Here the worker's own check is bypassed to let OpenCASCADE meet the file.
    """
    from planner.meshio import step_worker

    worker = Path(step_worker.__file__).read_text()
    bypass = Path(mesh_load.cache_dir()) / "worker_without_checks.py"  # type: ignore[arg-type]
    bypass.parent.mkdir(parents=True, exist_ok=True)
    bypass.write_text(worker.replace("    _check_acyclic(instances)\n", ""))
    monkeypatch.setattr("planner.meshio.step._WORKER", bypass)
    err = _refused("parse", _self_referencing())
    assert "crashed" in err.message and "SIGSEGV" in err.message


def test_a_tessellation_above_the_face_cap_is_refused_before_it_is_parsed() -> None:
    data = step_text([Part("c", (Cylinder(0.0, 0.0, 1000.0, 0.0, 2000.0),))], "mm").encode()
    err = _refused("face_count", data, tessellation_tolerance_m=1e-5, limits=MeshLimits(max_faces=1000))
    assert err.details["n_faces"] > 1000 and "tessellation_tolerance_m" in err.message


def test_the_worker_time_limit_stops_a_long_tessellation() -> None:
    data = step_text([Part("c", (Cylinder(0.0, 0.0, 1000.0, 0.0, 2000.0),))], "mm").encode()
    started = time.perf_counter()
    err = _refused("step_timeout", data, limits=MeshLimits(step_timeout_s=0.05))
    assert time.perf_counter() - started < 5.0
    assert err.details["timeout_s"] == 0.05


def test_the_worker_memory_limit_is_a_refusal() -> None:
    """64 MiB of address space cannot hold OpenCASCADE's libraries: the worker fails, the caller lives."""
    err = _refused("step_memory", _box_file("mm"), limits=MeshLimits(step_memory_bytes=64 * 1024**2))
    assert err.details["step_memory_bytes"] == 64 * 1024**2


@pytest.mark.parametrize("tol", [0.0, 1e-7, 0.02, float("nan")])
def test_tolerance_outside_its_bounds_is_refused(tol: float) -> None:
    _refused("tolerance", _box_file("mm"), tessellation_tolerance_m=tol)


def test_tolerance_is_refused_for_triangle_formats() -> None:
    from tests.meshio.test_load import box_mesh, export

    _refused("tolerance", export(box_mesh(), "stl"), name="b.stl", tessellation_tolerance_m=1e-4)


def test_tessellate_step_reports_what_it_did() -> None:
    tess = tessellate_step("c.step", _box_file("inch"), 1e-4, MeshLimits())
    assert tess.file_units == ("inch",) and tess.n_triangles == 12 and tess.glb[:4] == b"glTF"


def test_comments_and_strings_do_not_fool_the_reference_check() -> None:
    """A comment or a string holding ``;`` and ``#n`` references is neither an entity nor a reference."""
    text = _box_file("mm").decode()
    text = text.replace("DATA;\n", "DATA;\n/* #3=LOOP(#3); a comment; #1 */\n", 1)
    text = text.replace("PRODUCT('b','b'", "PRODUCT('b;#7=X(#7)','b'", 1)
    mesh = load_mesh(text.encode(), units="m", name="commented.step")
    assert mesh.report.n_faces == 12
