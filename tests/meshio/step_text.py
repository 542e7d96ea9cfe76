"""Small STEP (ISO 10303-21, AP214) files written as text, for the tests and the README's walk-through.

The tests make their own STEP files: boxes and cylinders as exact B-rep solids (planes, cylindrical
surfaces, lines and circles), in millimetres, metres or inches, as one part or as an assembly of placed
parts (``NEXT_ASSEMBLY_USAGE_OCCURRENCE`` with an ``ITEM_DEFINED_TRANSFORMATION``), so that the importer's
unit handling, assembly flattening and chordal deviation can be checked against known geometry.

``python -m tests.meshio.step_text OUT.step`` writes the walk-through's box cabin (an assembly, in mm).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: Length units: the unit entity of the file, and metres per unit.
UNITS = {"mm": 1e-3, "m": 1.0, "inch": 0.0254}


@dataclass(frozen=True)
class Box:
    """An axis-aligned box solid, corners in the part's frame (in the file's unit)."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]


@dataclass(frozen=True)
class Cylinder:
    """A solid cylinder along z: axis through (cx, cy), radius r, from z0 to z1 (the file's unit)."""

    cx: float
    cy: float
    r: float
    z0: float
    z1: float


Solid = Box | Cylinder


@dataclass(frozen=True)
class Part:
    """A named part (its solids) placed in the assembly at ``(R, p)`` (p in the file's unit)."""

    name: str
    solids: tuple[Solid, ...]
    R: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    p: tuple[float, float, float] = (0.0, 0.0, 0.0)


def _f(x: float) -> str:
    s = repr(float(x)).upper()
    if "E" not in s and "." not in s:
        s += "."
    if "E" in s and "." not in s.split("E")[0]:
        mant, exp = s.split("E")
        s = f"{mant}.E{exp}"
    return s


def _pt(p: tuple[float, ...] | np.ndarray) -> str:
    return "(" + ",".join(_f(v) for v in p) + ")"


@dataclass
class _Writer:
    lines: list[str] = field(default_factory=list)

    def add(self, text: str) -> int:
        self.lines.append(text)
        return len(self.lines)

    def ref(self, text: str) -> str:
        return f"#{self.add(text)}"

    def point(self, p: tuple[float, ...] | np.ndarray) -> str:
        return self.ref(f"CARTESIAN_POINT('',{_pt(p)})")

    def vertex(self, p: tuple[float, ...] | np.ndarray) -> str:
        return self.ref(f"VERTEX_POINT('',{self.point(p)})")

    def face(self, loop: str, surface: str) -> str:
        bound = self.ref(f"FACE_OUTER_BOUND('',{loop},.T.)")
        return self.ref(f"ADVANCED_FACE('',({bound}),{surface},.T.)")

    def axis(self, origin: tuple[float, ...], z: tuple[float, ...], x: tuple[float, ...]) -> str:
        o = self.ref(f"CARTESIAN_POINT('',{_pt(origin)})")
        dz = self.ref(f"DIRECTION('',{_pt(z)})")
        dx = self.ref(f"DIRECTION('',{_pt(x)})")
        return self.ref(f"AXIS2_PLACEMENT_3D('',{o},{dz},{dx})")

    def box(self, b: Box) -> str:
        lo, hi = np.array(b.lo, float), np.array(b.hi, float)
        corners = [np.array([(hi if (i >> k) & 1 else lo)[k] for k in range(3)]) for i in range(8)]
        verts = [self.vertex(c) for c in corners]
        edges: dict[tuple[int, int], str] = {}

        def edge(a: int, b_: int) -> str:
            key = (min(a, b_), max(a, b_))
            if key not in edges:
                d = corners[key[1]] - corners[key[0]]
                length = float(np.linalg.norm(d))
                direction = self.ref(f"DIRECTION('',{_pt(d / length)})")
                vec = self.ref(f"VECTOR('',{direction},{_f(length)})")
                line = self.ref(f"LINE('',{self.point(corners[key[0]])},{vec})")
                edges[key] = self.ref(f"EDGE_CURVE('',{verts[key[0]]},{verts[key[1]]},{line},.T.)")
            sense = ".T." if a < b_ else ".F."
            return self.ref(f"ORIENTED_EDGE('',*,*,{edges[key]},{sense})")

        # Corner index i has bit k set when coordinate k is at hi. Faces: loops counter-clockwise seen from
        # outside (outward normal), with the plane's normal along it.
        faces = [
            ((0, 2, 6, 4), (-1, 0, 0)),
            ((1, 5, 7, 3), (1, 0, 0)),
            ((0, 4, 5, 1), (0, -1, 0)),
            ((2, 3, 7, 6), (0, 1, 0)),
            ((0, 1, 3, 2), (0, 0, -1)),
            ((4, 6, 7, 5), (0, 0, 1)),
        ]
        refs = []
        for loop, normal in faces:
            oes = [edge(loop[i], loop[(i + 1) % 4]) for i in range(4)]
            el = self.ref("EDGE_LOOP('',(" + ",".join(oes) + "))")
            n = np.array(normal, float)
            xdir = corners[loop[1]] - corners[loop[0]]
            xdir = xdir / np.linalg.norm(xdir)
            plane = self.ref(f"PLANE('',{self.axis(tuple(corners[loop[0]]), tuple(n), tuple(xdir))})")
            refs.append(self.face(el, plane))
        shell = self.ref("CLOSED_SHELL('',(" + ",".join(refs) + "))")
        return self.ref(f"MANIFOLD_SOLID_BREP('box',{shell})")

    def cylinder(self, c: Cylinder) -> str:
        p0, p1 = (c.cx, c.cy, c.z0), (c.cx, c.cy, c.z1)
        z, x = (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)
        v0 = self.vertex((c.cx + c.r, c.cy, c.z0))
        v1 = self.vertex((c.cx + c.r, c.cy, c.z1))
        c0 = self.ref(f"CIRCLE('',{self.axis(p0, z, x)},{_f(c.r)})")
        c1 = self.ref(f"CIRCLE('',{self.axis(p1, z, x)},{_f(c.r)})")
        e0 = self.ref(f"EDGE_CURVE('',{v0},{v0},{c0},.T.)")
        e1 = self.ref(f"EDGE_CURVE('',{v1},{v1},{c1},.T.)")
        direction = self.ref(f"DIRECTION('',{_pt(z)})")
        vec = self.ref(f"VECTOR('',{direction},{_f(c.z1 - c.z0)})")
        seam_line = self.ref(f"LINE('',{self.point((c.cx + c.r, c.cy, c.z0))},{vec})")
        seam = self.ref(f"EDGE_CURVE('',{v0},{v1},{seam_line},.T.)")

        def oe(e: str, sense: bool) -> str:
            return self.ref(f"ORIENTED_EDGE('',*,*,{e},{'.T.' if sense else '.F.'})")

        side_edges = ",".join([oe(e0, True), oe(seam, True), oe(e1, False), oe(seam, False)])
        side_loop = self.ref(f"EDGE_LOOP('',({side_edges}))")
        side_surface = self.ref(f"CYLINDRICAL_SURFACE('',{self.axis(p0, z, x)},{_f(c.r)})")
        side = self.face(side_loop, side_surface)
        bottom_loop = self.ref(f"EDGE_LOOP('',({oe(e0, False)}))")
        bottom = self.face(bottom_loop, self.ref(f"PLANE('',{self.axis(p0, (0.0, 0.0, -1.0), x)})"))
        top_loop = self.ref(f"EDGE_LOOP('',({oe(e1, True)}))")
        top = self.face(top_loop, self.ref(f"PLANE('',{self.axis(p1, z, x)})"))
        shell = self.ref(f"CLOSED_SHELL('',({side},{bottom},{top}))")
        return self.ref(f"MANIFOLD_SOLID_BREP('cylinder',{shell})")


def step_text(parts: list[Part], units: str = "mm", *, assembly: str | None = None) -> str:
    """The STEP file of ``parts`` (one part alone when ``assembly`` is None, else an assembly of them).

    Args:
        parts: The parts; without an assembly there must be exactly one and its placement is ignored.
        units: ``mm``, ``m`` or ``inch``: the file's length unit (every coordinate is in it).
        assembly: The assembly product's name, or None for a single part file.
    """
    if units not in UNITS:
        raise ValueError(f"units must be one of {sorted(UNITS)}")
    if assembly is None and len(parts) != 1:
        raise ValueError("a single-part file holds exactly one part")
    w = _Writer()
    app = w.ref("APPLICATION_CONTEXT('automotive design')")
    w.add(f"APPLICATION_PROTOCOL_DEFINITION('international standard','automotive_design',2000,{app})")
    pctx = w.ref(f"PRODUCT_CONTEXT('',{app},'mechanical')")
    pdctx = w.ref(f"PRODUCT_DEFINITION_CONTEXT('part definition',{app},'design')")
    if units == "inch":
        mm = w.ref("( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) )")
        conv = w.ref(f"LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(25.4),{mm})")
        dims = w.ref("DIMENSIONAL_EXPONENTS(1.,0.,0.,0.,0.,0.,0.)")
        lu = w.ref(f"( CONVERSION_BASED_UNIT('INCH',{conv}) LENGTH_UNIT() NAMED_UNIT({dims}) )")
    else:
        prefix = ".MILLI." if units == "mm" else "$"
        lu = w.ref(f"( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT({prefix},.METRE.) )")
    au = w.ref("( NAMED_UNIT(*) PLANE_ANGLE_UNIT() SI_UNIT($,.RADIAN.) )")
    su = w.ref("( NAMED_UNIT(*) SI_UNIT($,.STERADIAN.) SOLID_ANGLE_UNIT() )")
    unc = w.ref(f"UNCERTAINTY_MEASURE_WITH_UNIT(LENGTH_MEASURE(1.E-07),{lu},'distance_accuracy_value','')")
    ctx = w.ref(
        f"( GEOMETRIC_REPRESENTATION_CONTEXT(3) GLOBAL_UNCERTAINTY_ASSIGNED_CONTEXT(({unc})) "
        f"GLOBAL_UNIT_ASSIGNED_CONTEXT(({lu},{au},{su})) REPRESENTATION_CONTEXT('',''))"
    )

    def product(name: str) -> tuple[str, str]:
        prod = w.ref(f"PRODUCT('{name}','{name}','',({pctx}))")
        pdf = w.ref(f"PRODUCT_DEFINITION_FORMATION('','',{prod})")
        pd = w.ref(f"PRODUCT_DEFINITION('design','',{pdf},{pdctx})")
        return pd, w.ref(f"PRODUCT_DEFINITION_SHAPE('','',{pd})")

    origin = (0.0, 0.0, 0.0)
    part_reps: list[tuple[str, str, str]] = []
    for part in parts:
        pd, pds = product(part.name)
        items = [w.box(s) if isinstance(s, Box) else w.cylinder(s) for s in part.solids]
        rep_origin = w.axis(origin, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0))
        listed = ",".join([rep_origin, *items])
        rep = w.ref(f"ADVANCED_BREP_SHAPE_REPRESENTATION('{part.name}',({listed}),{ctx})")
        w.add(f"SHAPE_DEFINITION_REPRESENTATION({pds},{rep})")
        part_reps.append((pd, rep, rep_origin))
    if assembly is not None:
        apd, apds = product(assembly)
        asm_origin = w.axis(origin, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0))
        placements = []
        for part in parts:
            R = np.array(part.R, float)
            placements.append(w.axis(part.p, tuple(R[:, 2]), tuple(R[:, 0])))
        listed = ",".join([asm_origin, *placements])
        arep = w.ref(f"SHAPE_REPRESENTATION('{assembly}',({listed}),{ctx})")
        w.add(f"SHAPE_DEFINITION_REPRESENTATION({apds},{arep})")
        for i, ((pd, rep, rep_origin), placement) in enumerate(zip(part_reps, placements, strict=True)):
            nauo = w.ref(
                f"NEXT_ASSEMBLY_USAGE_OCCURRENCE('{i + 1}','{parts[i].name}:{i + 1}','',{apd},{pd},$)"
            )
            npds = w.ref(f"PRODUCT_DEFINITION_SHAPE('','',{nauo})")
            idt = w.ref(f"ITEM_DEFINED_TRANSFORMATION('','',{rep_origin},{placement})")
            rr = w.ref(
                f"( REPRESENTATION_RELATIONSHIP('','',{rep},{arep}) "
                f"REPRESENTATION_RELATIONSHIP_WITH_TRANSFORMATION({idt}) "
                "SHAPE_REPRESENTATION_RELATIONSHIP() )"
            )
            w.add(f"CONTEXT_DEPENDENT_SHAPE_REPRESENTATION({rr},{npds})")
    body = "\n".join(f"#{i}={line};" for i, line in enumerate(w.lines, start=1))
    return (
        "ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION(('cabinplan test geometry'),'2;1');\n"
        "FILE_NAME('test.step','2024-01-01T00:00:00',('cabinplan'),(''),'tests.meshio.step_text','','');\n"
        "FILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));\nENDSEC;\nDATA;\n"
        f"{body}\nENDSEC;\nEND-ISO-10303-21;\n"
    )


def box_cabin_parts() -> list[Part]:
    """The walk-through's cabin in mm: a deck, two side walls, a ceiling, end walls and an overhead duct.

    A rectangular section around the reference cabins' rail (the base frame: z along the cabin, y up, x
    lateral; ``meshes/README.md``): the deck top at y = -160 mm, walls at x = +-1200 mm, the ceiling at
    y = 1800 mm, ends at z = -500 and 6500 mm; the duct (r = 100 mm) runs along the ceiling's -x corner.
    Each part is stored around its own origin and placed by the assembly.
    """

    def slab(name: str, lo: tuple[float, float, float], hi: tuple[float, float, float]) -> Part:
        centre = tuple((a + b) / 2 for a, b in zip(lo, hi, strict=True))
        half = tuple((b - a) / 2 for a, b in zip(lo, hi, strict=True))
        local = Box(tuple(-h for h in half), half)  # type: ignore[arg-type]
        return Part(name, (local,), p=centre)  # type: ignore[arg-type]

    return [
        slab("deck", (-1240.0, -200.0, -500.0), (1240.0, -160.0, 6500.0)),
        slab("wall_left", (-1240.0, -200.0, -500.0), (-1200.0, 1840.0, 6500.0)),
        slab("wall_right", (1200.0, -200.0, -500.0), (1240.0, 1840.0, 6500.0)),
        slab("ceiling", (-1240.0, 1800.0, -500.0), (1240.0, 1840.0, 6500.0)),
        slab("end_front", (-1240.0, -200.0, -540.0), (1240.0, 1840.0, -500.0)),
        slab("end_back", (-1240.0, -200.0, 6500.0), (1240.0, 1840.0, 6540.0)),
        Part("duct", (Cylinder(0.0, 0.0, 100.0, 0.0, 6800.0),), p=(-1050.0, 1650.0, -400.0)),
    ]


def main() -> None:
    """Write the walk-through's box cabin (an assembly in mm)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    args = parser.parse_args()
    args.out.write_text(step_text(box_cabin_parts(), "mm", assembly="cabin"))


if __name__ == "__main__":
    main()
