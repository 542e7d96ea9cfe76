"""Write generated cabins and scenarios (``planner.generate``) into a folder.

Run: ``python -m bench.generate --out DIR [--count N] [--seed S] [--start I] [--family F]`` (the same as
``cabinplan generate``). Every scenario is an ordinary scenario file (YAML + its mesh file) that
``cabinplan plan DIR/<name>.yaml -o out.json`` plans; ``DIR/manifest.json`` lists the cases and their
features (goal kind, shell, free space per side, mesh format and units, ...).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from planner.generate import FAMILIES, GeneratorOptions, generate_case, write_case, write_manifest


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--count", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--start", type=int, default=0, help="index of the first case")
    parser.add_argument("--clearance-m", type=float, default=0.01)
    parser.add_argument("--rail-length-m", type=float, default=6.0, help="3 to 6 m (shorter cabins)")
    parser.add_argument("--family", choices=list(FAMILIES), default="mixed", help="family of cabins")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    options = GeneratorOptions(
        clearance_m=args.clearance_m, rail_length_m=args.rail_length_m, family=args.family
    )
    cases = []
    for index in range(args.start, args.start + args.count):
        case = generate_case(args.seed, index, options)
        path = write_case(case, args.out)
        print(f"{path}: {case.meta['goal']}, {case.meta['format']} in {case.meta['units']}")
        cases.append(case)
    print(write_manifest(cases, args.out, args.seed))


if __name__ == "__main__":
    main()
