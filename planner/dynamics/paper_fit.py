"""Stiffness data that reproduce the paper's Table 2 (issue 15): ``python -m planner.dynamics.paper_fit``.

The paper (hybrid-8dof-cabin-robot, section 5.2) loads the tool with 50 random six-dimensional wrenches,
forces 0-1000 N and moments 0-1 N m per component, and tabulates the theoretical (MATLAB, its stiffness
model) and simulated (ANSYS) deflections along X, Y, Z; it prints 11 of the 50 rows (:data:`TABLE2_MM`)
and concludes that "the X direction has the best stiffness". It gives neither the posture nor any drive
stiffness, section or pin data. This script chooses those unknowns so that our model, at a documented
posture (:data:`POSTURE`, the home configuration), reproduces the statistics of the theory columns.

**Targets.** Per axis, the median and the maximum of |deflection| over the printed rows
(:data:`TARGET_MEDIAN_MM`, :data:`TARGET_MAX_MM`). The model's statistics are taken over a large seeded set
of loads of the same distribution: the median, and the 98th percentile as the expected maximum of 50
draws (the k-th of n order statistics sits near quantile k/(n+1); 50/51 = 0.98). Residuals are the log
ratios model/paper, plus a hinge that keeps the x median and maximum below those of y and z by 10%.

**Unknowns** (:data:`FIT_GROUPS`, log multipliers of the nominal issue-7 data,
:mod:`planner.dynamics.stiffness_params`): the rail, the three sliders (one stiffness: the paper's sliders
are identical), theta3, theta4, d5, theta6; the section scales of AB and CD (one), EF, the platform, the
column, the arm and the slide; the pin compliance. Thirteen unknowns for eight targets: the least-squares
problem carries a weak prior (weight :data:`PRIOR_WEIGHT` on every log multiplier) that keeps each unknown
at its nominal value unless the targets need it to move, and physical bounds (:data:`BOUNDS`). The result
is one of many data sets consistent with Table 2, not *the* robot's data: only a calibration on the real
cell (``cabinplan stiffness calibrate``) measures them.

Base axes: the paper's X, Y, Z are read as our base axes (x lateral, y up, z along the rail). The paper
does not define its deflection axes; with this reading "x the stiffest" holds at the home posture, where
the arm points along x and x loads the arm axially.
"""

from __future__ import annotations

import argparse
import logging
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from planner.core.description import LinkSections, Section, StiffnessSpec
from planner.dynamics.stiffness import StiffnessModel
from planner.dynamics.stiffness_params import ParameterSet, reference_values, stiffness_yaml_block
from planner.robots.cabin8 import Cabin8, default_description_path

Array = NDArray[np.float64]
log = logging.getLogger(__name__)

#: Table 2 of the paper (hybrid-8dof-cabin-robot, section 5.2), theory columns dx, dy, dz [mm] of the 11
#: printed load cases f1-f6, f46-f50 (the simulation columns are not a target: they are ANSYS's answer
#: to the same unknown structure).
TABLE2_MM = np.array(
    [
        [0.035, 0.059, 0.037],
        [0.011, 0.231, 0.197],
        [0.033, 0.122, 0.088],
        [0.020, 0.215, 0.149],
        [0.017, 0.131, 0.091],
        [0.021, 0.186, 0.129],
        [0.015, 0.162, 0.128],
        [0.024, 0.267, 0.215],
        [0.003, 0.058, 0.037],
        [0.001, 0.138, 0.087],
        [0.016, 0.160, 0.135],
    ]
)
TARGET_MEDIAN_MM = np.median(TABLE2_MM, axis=0)
TARGET_MAX_MM = TABLE2_MM.max(axis=0)
#: Table 2's load ranges: every force component uniform in [0, 1000] N, every moment in [0, 1] N m.
FORCE_RANGE_N = (0.0, 1000.0)
MOMENT_RANGE_NM = (0.0, 1.0)
#: The posture of the fit (joints; the paper does not give its posture): the platform centred at
#: y = 0.31 m and level, the arm turned along the cabin axis (theta3 = 90 deg), theta4 = -0.5 rad, the slide
#: at d5 = -0.1 m. At the home posture (arm sideways, theta3 = 0) no data within the bounds reproduce Table 2
#: (the stage's rotation couples x and y there and keeps x softer than y by 2x); a search over 75 postures
#: found the arm along the cabin axis the best (issue 15).
POSTURE = {
    "d1": 0.3,
    "x": 0.0,
    "y": 0.31,
    "gamma": 0.0,
    "theta3": math.pi / 2,
    "theta4": -0.5,
    "d5": -0.1,
    "theta6": 0.0,
}
#: Fit variables (parameters moved together); see :mod:`planner.dynamics.stiffness_params`.
FIT_GROUPS: tuple[tuple[str, ...], ...] = (
    ("k.d1",),
    ("k.x1", "k.x2", "k.x3"),
    ("k.theta3",),
    ("k.theta4",),
    ("k.d5",),
    ("k.theta6",),
    ("s.link_ab", "s.link_cd"),
    ("s.link_ef",),
    ("s.platform",),
    ("s.column",),
    ("s.arm",),
    ("s.slide",),
    ("pin",),
)
#: Physical bounds of each variable's value (drives [N/m | N m/rad], section scales [1], pin [m/N]):
#: ball-screw / gear drives of a machine this size, sections that still fit the mechanism, pins from a
#: stiff preloaded pair (1e-11 m/N) to a plain bushing (1e-8 m/N).
BOUNDS: tuple[tuple[float, float], ...] = (
    (1e7, 2e9),
    (1e7, 2e9),
    (1e6, 1e9),
    (1e6, 1e9),
    (1e7, 2e9),
    (1e5, 1e8),
    (0.5, 3.0),
    (0.5, 3.0),
    (0.5, 2.0),
    (0.5, 2.0),
    (0.5, 2.0),
    (0.5, 2.0),
    (1e-11, 1e-8),
)
PRIOR_WEIGHT = 0.05
#: The prior's centre: the issue-7 guesses (what cabin8.yaml held before this fit), so that the fit is
#: reproducible whatever the description file holds now.
NOMINAL_ISSUE7 = StiffnessSpec(
    E_Pa=2.06e11,
    G_Pa=7.94e10,
    sections=LinkSections(
        link_ab=Section(b=0.06, h=0.03),
        link_cd=Section(b=0.06, h=0.03),
        link_ef=Section(b=0.04, h=0.02),
        platform=Section(b=0.25, h=0.08),
        column=Section(b=0.14, h=0.12),
        arm=Section(b=0.14, h=0.10),
        slide=Section(b=0.10, h=0.08),
    ),
    drives={
        "d1": 5.0e7,
        "x1": 2.0e7,
        "x2": 2.0e7,
        "x3": 2.0e7,
        "theta3": 5.0e6,
        "theta4": 5.0e6,
        "d5": 2.0e7,
        "theta6": 1.0e6,
    },
    source="nominal",
)
#: Loads of the fit's statistics and the expected-maximum quantile of 50 draws.
FIT_LOADS = 20000
MAX_QUANTILE = 50.0 / 51.0
ORDER_MARGIN = 0.1
#: Finite-difference step of the fit's Jacobian in log multipliers (the statistics are piecewise smooth).
DIFF_STEP = 1e-2
SEED = 15


def table2_loads(n: int, seed: int) -> Array:
    """N random wrenches (n, 6) of Table 2's distribution (forces [N], moments [N m], base axes)."""
    rng = np.random.default_rng(seed)
    return np.hstack([rng.uniform(*FORCE_RANGE_N, (n, 3)), rng.uniform(*MOMENT_RANGE_NM, (n, 3))])


def posture_joints(robot: Cabin8) -> Array:
    """Joint vector (8,) of :data:`POSTURE`."""
    return robot.joints_from_dict(dict(POSTURE), field="posture")


@dataclass(frozen=True)
class Table2Stats:
    """|deflection| statistics per axis [mm]: median, maximum (or expected maximum), x stiffest."""

    median_mm: Array
    max_mm: Array

    @property
    def x_stiffest(self) -> bool:
        """X has the smallest median and maximum |deflection|."""
        return bool(self.median_mm[0] < self.median_mm[1:].min() and self.max_mm[0] < self.max_mm[1:].min())

    def ratios(self) -> Array:
        """(2, 3): median and maximum over the paper's."""
        return np.vstack([self.median_mm / TARGET_MEDIAN_MM, self.max_mm / TARGET_MAX_MM])


def table2_stats(C: Array, loads: Array, expected_max: bool = False) -> Table2Stats:
    """Statistics of |C W| [mm] for the wrenches W (n, 6) at the tool (C the 6x6 tool compliance)."""
    d = np.abs(loads @ C[:3].T) * 1e3
    top = np.quantile(d, MAX_QUANTILE, axis=0) if expected_max else d.max(axis=0)
    return Table2Stats(np.median(d, axis=0), top)


@dataclass(frozen=True)
class PaperFit:
    """Result of :func:`fit_table2`."""

    spec: StiffnessSpec
    labels: tuple[str, ...]
    values: tuple[float, ...]
    stats: Table2Stats
    cost: float
    nfev: int


def fit_table2(
    robot: Cabin8 | None = None,
    base: StiffnessSpec | None = None,
    q: Array | None = None,
    n_loads: int = FIT_LOADS,
) -> PaperFit:
    """Least-squares fit of the unknown stiffness data to Table 2's theory statistics (module docstring).

    Args:
        robot: The geometry (default: the packaged cabin8).
        base: The nominal data the prior pulls towards (default: :data:`NOMINAL_ISSUE7`).
        q: The posture (8,) (default: :data:`POSTURE`).
        n_loads: Loads of the statistics.
    """
    robot = robot or Cabin8()
    base = base or NOMINAL_ISSUE7
    pset = ParameterSet.of(base, FIT_GROUPS)
    q = posture_joints(robot) if q is None else np.asarray(q, dtype=float)
    loads = table2_loads(n_loads, SEED)
    # The prior's centre: the nominal values (a rigid nominal pin -> the reference pin compliance).
    theta0 = np.where(pset.theta_of(base) < -50.0, 0.0, pset.theta_of(base))
    lo = np.log([b[0] for b in BOUNDS]) - np.log(_ref_values(pset))
    hi = np.log([b[1] for b in BOUNDS]) - np.log(_ref_values(pset))
    theta0 = np.clip(theta0, lo + 1e-9, hi - 1e-9)
    start = theta0

    def residuals(theta: Array) -> Array:
        C = StiffnessModel(robot, pset.spec(theta)).compliance(q)
        st = table2_stats(C, loads, expected_max=True)
        r_fit = np.concatenate([np.log(st.median_mm / TARGET_MEDIAN_MM), np.log(st.max_mm / TARGET_MAX_MM)])
        order = [
            max(0.0, np.log(st.median_mm[0] / st.median_mm[1:].min()) + ORDER_MARGIN),
            max(0.0, np.log(st.max_mm[0] / st.max_mm[1:].min()) + ORDER_MARGIN),
        ]
        return np.concatenate([r_fit, order, PRIOR_WEIGHT * (theta - theta0)])

    sol = least_squares(
        residuals,
        start,
        bounds=(lo, hi),
        x_scale=1.0,
        diff_step=DIFF_STEP,
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
    )
    spec = pset.spec(sol.x)
    C = StiffnessModel(robot, spec).compliance(q)
    values = tuple(float(v) for v in _ref_values(pset) * np.exp(sol.x))
    return PaperFit(spec, pset.labels, values, table2_stats(C, loads, True), float(sol.cost), int(sol.nfev))


def _ref_values(pset: ParameterSet) -> Array:
    ref = reference_values(pset.base)
    return np.array([ref[g[0]] for g in pset.groups])


def replace_stiffness_block(text: str, block: str) -> str:
    """A description file's text with its top-level ``stiffness:`` section replaced by ``block``.

    The section runs from the ``stiffness:`` line to the next line starting in column 0 (the next key, or
    an unindented comment) or the end; without one, the block is appended.
    """
    m = re.search(r"^stiffness:.*?(?=^\S|\Z)", text, flags=re.S | re.M)
    if m is None:
        return text.rstrip("\n") + "\n\n" + block
    return text[: m.start()] + block + "\n" + text[m.end() :]


def _comment(fit: PaperFit) -> list[str]:
    r = fit.stats.ratios()
    return [
        "Issue 15: fitted by `python -m planner.dynamics.paper_fit` so that the model reproduces the paper's",
        "Table 2 (theory columns) at paper_fit.POSTURE (arm along the cabin axis): per axis, median and",
        "expected maximum of |deflection| over loads of 0-1000 N / 0-1 N m. Model/paper ratios,",
        "median x y z: "
        + " ".join(f"{v:.3f}" for v in r[0])
        + "; maximum: "
        + " ".join(f"{v:.3f}" for v in r[1])
        + ".",
        "The paper gives no drive, section or pin data: these are one data set consistent with its",
        "Table 2 (a weak prior keeps each unknown near the issue-7 guess), not measurements.",
        "E and G are steel's (not fitted). Calibrate the real cell with `cabinplan stiffness calibrate`.",
        "Sections are rectangles b x h [m] with b >= h: b along the link's local z axis (for the stage",
        "links and the platform the base z axis, normal to the stage plane), h in the plane it bends in.",
    ]


def main(argv: list[str] | None = None) -> int:
    """Run the fit, print the figures; ``--write`` puts the result into a description file."""
    ap = argparse.ArgumentParser(
        prog="python -m planner.dynamics.paper_fit", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--description", type=Path, default=None, help="base description (default: cabin8)")
    ap.add_argument("--write", action="store_true", help="replace the description's stiffness section")
    ap.add_argument("--nominal", type=Path, default=None, help="nominal data for the prior (a description)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stdout)
    path = args.description or default_description_path()
    robot = Cabin8(path)
    base = Cabin8(args.nominal).desc.stiffness if args.nominal else NOMINAL_ISSUE7
    fit = fit_table2(robot, base)
    log.info("fit: cost %.3g after %d evaluations", fit.cost, fit.nfev)
    for label, v in zip(fit.labels, fit.values, strict=True):
        log.info("  %-28s %.4g", label, v)
    r = fit.stats.ratios()
    log.info("paper median x y z [mm]: %s", np.round(TARGET_MEDIAN_MM, 4))
    log.info("model median x y z [mm]: %s  ratio %s", np.round(fit.stats.median_mm, 4), np.round(r[0], 3))
    log.info("paper max    x y z [mm]: %s", np.round(TARGET_MAX_MM, 4))
    log.info("model E[max] x y z [mm]: %s  ratio %s", np.round(fit.stats.max_mm, 4), np.round(r[1], 3))
    log.info("x stiffest: %s", fit.stats.x_stiffest)
    spec = fit.spec.model_copy(update={"source": "paper-fit"})
    block = stiffness_yaml_block(spec, _comment(fit))
    if args.write:
        path.write_text(replace_stiffness_block(path.read_text(encoding="utf-8"), block), encoding="utf-8")
        log.info("wrote %s", path)
    else:
        log.info("%s", block)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
