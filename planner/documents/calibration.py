"""``cabinplan stiffness calibrate``: read the measurements, fit, write the calibrated description.

The file side of :mod:`planner.dynamics.calibration` (which parses and fits): the measurement CSV is read
here, and the base description's text is written back with its stiffness section replaced, validated before
anything is written and read back as the planner will.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from planner.core.description import Hybrid8Description
from planner.core.exceptions import InvalidInput, InvalidRobotDescription
from planner.dynamics.calibration import DEFAULT_PARAMETERS, Calibration, calibrate, parse_measurements
from planner.dynamics.stiffness_params import stiffness_yaml_block
from planner.robots.cabin8 import Cabin8


def calibrated_description(base_path: Path, calibration: Calibration) -> str:
    """The base description file's text with its stiffness section replaced by the calibrated one."""
    from planner.dynamics.paper_fit import replace_stiffness_block

    block = stiffness_yaml_block(
        calibration.spec,
        [
            "Calibrated (issue 15) by `cabinplan stiffness calibrate`: see note and uncertainty.",
            "Sections are rectangles b x h [m] (b along the link's local z axis), drives N/m or N m/rad.",
        ],
    )
    return replace_stiffness_block(base_path.read_text(encoding="utf-8"), block)


def calibrate_file(
    measurements: Path,
    output: Path,
    description: Path | None = None,
    parameters: Sequence[str] | None = None,
    sigma_m: float = 1e-5,
    sigma_rad: float = 1e-5,
) -> dict[str, Any]:
    """``cabinplan stiffness calibrate``: read the CSV, fit, write the calibrated description, report.

    Raises:
        InvalidInput: unreadable files, bad data (see :func:`parse_measurements`, :func:`calibrate`).
        CalibrationIllPosed: see :func:`calibrate`.
    """
    from planner.core.description import load_description
    from planner.robots.cabin8 import default_description_path

    base_path = (description or default_description_path()).resolve()
    robot = Cabin8(base_path)
    try:
        text = measurements.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInput(f"measurements: cannot read {measurements} ({exc})", field="measurements") from exc
    data = parse_measurements(text, robot.desc.gravity_m_s2, source="measurements")
    cal = calibrate(robot, data, parameters or DEFAULT_PARAMETERS, sigma_m, sigma_rad)
    out_text = calibrated_description(base_path, cal)
    try:
        Hybrid8Description.model_validate(yaml.safe_load(out_text))  # valid before anything is written
    except (ValidationError, yaml.YAMLError) as exc:
        raise InvalidRobotDescription(
            f"calibration: the calibrated description would not be valid ({exc}); check {base_path}",
            path=str(base_path),
        ) from exc
    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_text(out_text, encoding="utf-8")
    except OSError as exc:
        raise InvalidInput(f"--output: cannot write {output} ({exc.strerror})", field="output") from exc
    load_description(output)  # what the planner will read back
    return {"robot": robot.name, "description": str(output), "source": "calibrated", **cal.to_dict()}


__all__ = ["calibrate_file", "calibrated_description"]
