"""Stiffness calibration from measured deflections (issue 15): the fit of ``cabinplan stiffness calibrate``.

A cell measures, at several configurations, the tool's pose offset under a known load (a laser tracker
before and after hanging a weight or pulling with a force gauge). The model predicts that offset as
``x_i = C(q_i; p) w_i`` (:class:`~planner.dynamics.stiffness.StiffnessModel`: the compliance at the tool
origin, base axes; the robot's own weight cancels in the difference, the model being linear), and the
parameters p (:mod:`planner.dynamics.stiffness_params`) are chosen by weighted nonlinear least squares
on ``theta = log(p / p_ref)``:

    minimise  sum_i |(x_i - C(q_i; p) w_i) / sigma|^2,

sigma being the measurement's standard deviation (translation ``sigma_m``, rotation ``sigma_rad``).

**Uncertainty.** With the weighted residual Jacobian J (scaled to the residual's estimated standard
deviation s^2 = |r|^2 / (m - n)) at the solution, the covariance of theta is ``s^2 (J^T J)^-1`` (Gauss-
Newton); since theta is a log, its standard deviation is the parameter's *relative* standard deviation.

**Refusals** (:class:`~planner.core.exceptions.CalibrationIllPosed`), before and after the fit:

* fewer scalar measurements than parameters + 1, or fewer than :data:`MIN_CONFIGURATIONS` distinct
  configurations (two configurations closer than :data:`SAME_CONFIGURATION` in every drive count once);
* at the nominal parameters and at the solution, J (columns scaled to unit norm, so the test is about the
  directions, not the parameters' sizes) has a condition number above :data:`MAX_CONDITION`: some
  combination of parameters does not change the predicted deflections (too similar configurations or
  loads, or a parameter no load excites); the message names the combination;
* a parameter's relative standard deviation is above :data:`MAX_RELATIVE_STD`: the data do not determine
  it (the message names it; leave it out with ``--parameters`` or measure loads that excite it).

The file format is :data:`CSV_COLUMNS` (one row per measurement, SI units in the column names). Reading
the measurement file and writing the calibrated description (the CLI's use case) is
:mod:`planner.documents.calibration`; this module parses and fits.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from planner.core.description import HYBRID8_DRIVES, StiffnessSpec
from planner.core.exceptions import CalibrationIllPosed, InvalidInput
from planner.core.types import Array
from planner.dynamics.stiffness import StiffnessModel
from planner.dynamics.stiffness_params import (
    PARAMETERS,
    ParameterSet,
    check_names,
    parameter_unit,
    reference_values,
)
from planner.robots.cabin8 import Cabin8

_UNITS = {"d1": "m", "x1": "m", "x2": "m", "x3": "m", "theta3": "rad", "theta4": "rad", "d5": "m"}
DRIVE_COLUMNS = tuple(f"{d}_{_UNITS.get(d, 'rad')}" for d in HYBRID8_DRIVES)
WRENCH_COLUMNS = ("fx_N", "fy_N", "fz_N", "mx_Nm", "my_Nm", "mz_Nm")
TRANSLATION_COLUMNS = ("dx_m", "dy_m", "dz_m")
ROTATION_COLUMNS = ("rx_rad", "ry_rad", "rz_rad")
#: Required columns, then the optional ones: ``payload_kg`` (a weight hung at the tool origin, added to the
#: wrench as m g) and the measured rotation (without it only the translations are fitted).
CSV_COLUMNS = (*DRIVE_COLUMNS, *WRENCH_COLUMNS, *TRANSLATION_COLUMNS)
OPTIONAL_COLUMNS = ("payload_kg", *ROTATION_COLUMNS)
#: Default parameters calibrated: those the paper-fit model's deflections are most sensitive to (the d5
#: and theta6 drives, the AB and CD links and the slide). The others are so stiff there that 1 kN loads
#: and 0.01 mm measurements cannot determine them to 5% (relative standard deviations from 4% for theta4
#: to several hundred % on 120 measurements at 20 configurations); name them with ``--parameters`` when a
#: cell is softer there -- the calibration refuses when the data cannot determine them.
DEFAULT_PARAMETERS: tuple[str, ...] = ("k.d5", "k.theta6", "s.link_ab", "s.link_cd", "s.slide")

MIN_CONFIGURATIONS = 3
SAME_CONFIGURATION = 1e-3
MAX_CONDITION = 1e6
MAX_RELATIVE_STD = 0.5
MAX_ROWS = 100_000


@dataclass(frozen=True)
class Measurements:
    """Measured deflections: drive positions (N, 8), applied wrenches (N, 6), offsets (N, 6) [m, rad].

    ``has_rotation`` says whether the rotation columns were measured (else they are zero and unused).
    """

    drives: Array
    wrench: Array
    offset: Array
    has_rotation: bool

    def __len__(self) -> int:
        return int(self.drives.shape[0])


def parse_measurements(
    text: str, gravity_m_s2: Sequence[float], source: str = "measurements"
) -> Measurements:
    """Parse the CSV text (header :data:`CSV_COLUMNS` [+ :data:`OPTIONAL_COLUMNS`]).

    Raises:
        InvalidInput: a missing or unknown column, a non-numeric or non-finite cell (the message names the
            row and column), no rows, too many rows.
    """
    reader = csv.DictReader(io.StringIO(text))
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise InvalidInput(f"{source}: missing columns {missing} (need {list(CSV_COLUMNS)})", field=source)
    unknown = [c for c in header if c not in CSV_COLUMNS and c not in OPTIONAL_COLUMNS]
    if unknown:
        raise InvalidInput(
            f"{source}: unknown columns {unknown} (known: {list(CSV_COLUMNS) + list(OPTIONAL_COLUMNS)})",
            field=source,
        )
    rot = [c for c in ROTATION_COLUMNS if c in header]
    if rot and len(rot) != 3:
        raise InvalidInput(f"{source}: give all of {list(ROTATION_COLUMNS)} or none", field=source)
    rows: list[list[float]] = []
    cols = [*CSV_COLUMNS, "payload_kg", *ROTATION_COLUMNS]
    for i, raw in enumerate(reader, start=2):
        if len(rows) >= MAX_ROWS:
            raise InvalidInput(f"{source}: more than {MAX_ROWS} rows", field=source)
        row = {k.strip(): v for k, v in raw.items() if k is not None}
        vals = []
        for c in cols:
            cell = row.get(c)
            if cell is None or cell.strip() == "":
                if c in CSV_COLUMNS or (c in ROTATION_COLUMNS and rot):
                    raise InvalidInput(f"{source}: line {i}, column {c}: empty", field=source)
                vals.append(0.0)
                continue
            try:
                v = float(cell)
            except ValueError:
                raise InvalidInput(
                    f"{source}: line {i}, column {c}: not a number ({cell!r})", field=source
                ) from None
            if not math.isfinite(v):
                raise InvalidInput(f"{source}: line {i}, column {c}: not finite", field=source)
            vals.append(v)
        rows.append(vals)
    if not rows:
        raise InvalidInput(f"{source}: no measurements", field=source)
    a = np.array(rows)
    drives, wrench = a[:, :8], a[:, 8:14].copy()
    offset = np.hstack([a[:, 14:17], a[:, 18:21]])
    wrench[:, :3] += a[:, 17:18] * np.asarray(gravity_m_s2, dtype=float)[None, :]
    return Measurements(drives, wrench, offset, bool(rot))


def measurements_csv(m: Measurements) -> str:
    """CSV text of measurements (the inverse of :func:`parse_measurements`, without ``payload_kg``)."""
    header = [*CSV_COLUMNS, *(ROTATION_COLUMNS if m.has_rotation else ())]
    lines = [",".join(header)]
    for u, w, x in zip(m.drives, m.wrench, m.offset, strict=True):
        vals = [*u, *w, *x[:3], *(x[3:] if m.has_rotation else ())]
        lines.append(",".join(repr(float(v)) for v in vals))
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class Calibration:
    """Result of :func:`calibrate`.

    Attributes:
        spec: The calibrated stiffness data (``source: calibrated``, with ``uncertainty``).
        parameters: Calibrated parameter names.
        values: Their values (units: :func:`~planner.dynamics.stiffness_params.parameter_unit`).
        nominal: Their values in the base description.
        relative_std: Relative standard deviation of each value.
        residuals: Per measurement, the translation and rotation residual norms, (N, 2) [m, rad].
        rms_translation_m: RMS of the translation residual components.
        rms_rotation_rad: RMS of the rotation residual components (0 without rotation columns).
        condition: Condition number of the column-scaled weighted Jacobian at the solution.
        configurations: Distinct configurations in the data.
    """

    spec: StiffnessSpec
    parameters: tuple[str, ...]
    values: tuple[float, ...]
    nominal: tuple[float, ...]
    relative_std: tuple[float, ...]
    residuals: Array
    rms_translation_m: float
    rms_rotation_rad: float
    condition: float
    configurations: int

    def to_dict(self) -> dict[str, Any]:
        """JSON report: parameters with units, uncertainties, per-measurement residuals."""
        return {
            "parameters": [
                {
                    "name": n,
                    "value": v,
                    "nominal": v0,
                    "unit": parameter_unit(n),
                    "relative_std": s,
                }
                for n, v, v0, s in zip(
                    self.parameters, self.values, self.nominal, self.relative_std, strict=True
                )
            ],
            "rms_translation_m": self.rms_translation_m,
            "rms_rotation_rad": self.rms_rotation_rad,
            "condition": self.condition,
            "configurations": self.configurations,
            "measurements": len(self.residuals),
            "residuals": [
                {"row": i + 1, "translation_m": float(r[0]), "rotation_rad": float(r[1])}
                for i, r in enumerate(self.residuals)
            ],
        }


def distinct_configurations(drives: Array, tol: float = SAME_CONFIGURATION) -> int:
    """Number of configurations that differ by more than ``tol`` in some drive (greedy clustering)."""
    reps: list[Array] = []
    for u in drives:
        if not any(np.max(np.abs(u - r)) <= tol for r in reps):
            reps.append(u)
    return len(reps)


def _scaled_condition(J: Array) -> tuple[float, Array]:
    """Condition number of J with unit-norm columns and the right singular vector of its smallest value."""
    norms = np.linalg.norm(J, axis=0)
    if np.any(norms == 0):
        v = (norms == 0).astype(float)
        return math.inf, v / np.linalg.norm(v)
    _, s, vt = np.linalg.svd(J / norms, full_matrices=False)
    return (float(s[0] / s[-1]) if s[-1] > 0 else math.inf), vt[-1]


def _combination(labels: Sequence[str], v: Array) -> str:
    order = np.argsort(-np.abs(v))
    parts = [f"{v[i]:+.2f} {labels[i]}" for i in order[:4] if abs(v[i]) > 0.05]
    return " ".join(parts)


def calibrate(
    robot: Cabin8,
    data: Measurements,
    parameters: Sequence[str] = DEFAULT_PARAMETERS,
    sigma_m: float = 1e-5,
    sigma_rad: float = 1e-5,
) -> Calibration:
    """Least-squares stiffness calibration (module docstring).

    Args:
        robot: The robot whose description's stiffness data are the start and the reference.
        data: The measurements.
        parameters: Parameter names to fit (:data:`~planner.dynamics.stiffness_params.PARAMETERS`); the
            others keep the description's values.
        sigma_m: Standard deviation of a measured translation component [m] (relative weights only).
        sigma_rad: Standard deviation of a measured rotation component [rad].

    Raises:
        InvalidInput: unknown parameter names, a bad sigma, configurations outside the limits.
        CalibrationIllPosed: the data cannot determine the parameters (see the module docstring).
    """
    names = check_names(list(parameters))
    base = robot.desc.stiffness
    if base is None:
        raise InvalidInput(f"robot {robot.name}: the description has no stiffness section", field="robot")
    if not (sigma_m > 0 and sigma_rad > 0 and math.isfinite(sigma_m) and math.isfinite(sigma_rad)):
        raise InvalidInput("sigma: must be finite and > 0", field="sigma")
    q = robot.joints_from_drives(data.drives)
    bad = [i + 1 for i, qi in enumerate(q) if robot.violations(qi)]
    if bad:
        raise InvalidInput(
            f"measurements: rows {bad[:5]} are outside the robot's limits (drive positions)",
            field="measurements",
        )
    n_conf = distinct_configurations(data.drives)
    comps = 6 if data.has_rotation else 3
    m = comps * len(data)
    labels = names
    if m < len(names) + 1 or n_conf < MIN_CONFIGURATIONS:
        raise CalibrationIllPosed(
            f"calibration: too few measurements: {len(data)} rows ({m} measured components) at {n_conf} "
            f"distinct configurations for {len(names)} parameters; need more than {len(names)} components "
            f"at {MIN_CONFIGURATIONS} or more distinct configurations",
            rows=len(data),
            configurations=n_conf,
            parameters=list(names),
        )
    pset = ParameterSet.of(base, [(n,) for n in names])
    theta_base = pset.theta_of(base)
    theta0 = np.where(theta_base < -50.0, 0.0, theta_base)  # a rigid pin starts at the reference
    weights = np.array([1 / sigma_m] * 3 + [1 / sigma_rad] * 3)[:comps]

    def predict(theta: Array) -> Array:
        C = StiffnessModel(robot, pset.spec(theta)).compliance(q)
        return np.einsum("nij,nj->ni", C, data.wrench)

    def residuals(theta: Array) -> Array:
        return ((data.offset - predict(theta))[:, :comps] * weights).ravel()

    def jacobian(theta: Array, step: float = 1e-6) -> Array:
        r0 = residuals(theta)
        cols = []
        for k in range(len(theta)):
            t = theta.copy()
            t[k] += step
            cols.append((residuals(t) - r0) / step)
        return np.column_stack(cols)

    cond0, v0 = _scaled_condition(jacobian(theta0))
    if cond0 > MAX_CONDITION:
        raise CalibrationIllPosed(
            f"calibration: ill-posed data: the measurements do not separate the parameters (condition "
            f"number {cond0:.3g} > {MAX_CONDITION:g}); the combination {_combination(labels, v0)} (log "
            f"multipliers) leaves every predicted deflection unchanged. Measure at more varied "
            f"configurations and load directions ({n_conf} distinct configurations), or fit fewer parameters",
            condition=cond0,
            configurations=n_conf,
            combination=dict(zip(labels, v0.tolist(), strict=True)),
        )
    sol = least_squares(residuals, theta0, jac=lambda t: jacobian(t), method="lm", xtol=1e-12, ftol=1e-12)
    theta = sol.x
    J = jacobian(theta)
    cond, v = _scaled_condition(J)
    r = residuals(theta)
    dof = max(1, m - len(theta))
    s2 = float(r @ r) / dof
    if cond > MAX_CONDITION:
        raise CalibrationIllPosed(
            f"calibration: ill-posed at the solution (condition number {cond:.3g}); the combination "
            f"{_combination(labels, v)} is not determined by the data",
            condition=cond,
            combination=dict(zip(labels, v.tolist(), strict=True)),
        )
    cov = s2 * np.linalg.inv(J.T @ J)
    rel = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    loose = [f"{n} (+-{100 * s:.0f}%)" for n, s in zip(labels, rel, strict=True) if s > MAX_RELATIVE_STD]
    if loose:
        raise CalibrationIllPosed(
            f"calibration: the data do not determine {', '.join(loose)} (relative standard deviation above "
            f"{100 * MAX_RELATIVE_STD:.0f}%); leave them out (--parameters) or add loads that excite them",
            relative_std=dict(zip(labels, rel.tolist(), strict=True)),
        )
    ref = reference_values(base)
    values = tuple(ref[n] * math.exp(float(t)) for n, t in zip(labels, theta, strict=True))
    nominal = tuple(float(base.pin_compliance_m_N) if n == "pin" else ref[n] for n in labels)
    res = data.offset - predict(theta)
    per_row = np.column_stack(
        [
            np.linalg.norm(res[:, :3], axis=1),
            np.linalg.norm(res[:, 3:], axis=1) if data.has_rotation else 0 * res[:, 0],
        ]
    )
    note = (
        f"calibrated by `cabinplan stiffness calibrate` from {len(data)} measurements at {n_conf} "
        f"configurations; fitted: {', '.join(labels)}; the other data are the base description's "
        f"({base.source}); RMS residual {float(np.sqrt(np.mean(res[:, :3] ** 2))):.3g} m"
    )
    spec = pset.spec(
        theta,
        source="calibrated",
        note=note,
        uncertainty={n: float(s) for n, s in zip(labels, rel, strict=True)},
    )
    return Calibration(
        spec=spec,
        parameters=labels,
        values=values,
        nominal=nominal,
        relative_std=tuple(float(s) for s in rel),
        residuals=per_row,
        rms_translation_m=float(np.sqrt(np.mean(res[:, :3] ** 2))),
        rms_rotation_rad=float(np.sqrt(np.mean(res[:, 3:] ** 2))) if data.has_rotation else 0.0,
        condition=cond,
        configurations=n_conf,
    )


__all__ = [
    "CSV_COLUMNS",
    "DEFAULT_PARAMETERS",
    "OPTIONAL_COLUMNS",
    "PARAMETERS",
    "Calibration",
    "Measurements",
    "calibrate",
    "measurements_csv",
    "parse_measurements",
]
