"""pprs6.yaml: validated on load, errors name the field, hashed for provenance."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from planner.core.exceptions import InvalidRobotDescription
from planner.robots.pprs6 import Pprs6, default_description_path


def _write(tmp_path: Path, edit: dict) -> Path:
    raw = yaml.safe_load(default_description_path().read_text())
    raw.update(edit)
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(raw))
    return p


def test_packaged_description_matches_table_1() -> None:
    robot = Pprs6()
    g = robot.geometry
    assert (g.r, g.R, g.L) == (0.16, 0.18, (0.1, 0.12, 0.12))
    assert list(robot.limits.lower[3:]) == [0.0375] * 3 and list(robot.limits.upper[:2]) == [0.18] * 2
    assert len(robot.description_sha256) == 64


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        ({"chains": [{"name": "a", "joints": ["P", "P", "R", "S"]}] * 3}, "chains"),
        ({"drives": []}, "drives"),
        (
            {
                "geometry": {
                    "platform_radius": -1,
                    "base_radius": 0.18,
                    "link_lengths": [0.1, 0.1, 0.1],
                    "support_angles": [0, 2, 4],
                }
            },
            "geometry.platform_radius",
        ),
        ({"sample_period_s": 0}, "sample_period_s"),
        ({"extra": 1}, "extra"),
    ],
)
def test_errors_name_the_field(tmp_path: Path, edit: dict, field: str) -> None:
    with pytest.raises(InvalidRobotDescription) as exc:
        Pprs6(_write(tmp_path, edit))
    # schema errors carry the field's path; structural checks name it in the message
    assert exc.value.details["field"] == field or (
        exc.value.details["field"] == "<root>" and field in str(exc.value)
    )


def test_registered_by_name() -> None:
    from planner.core.exceptions import InvalidInput
    from planner.robots import available_robots, load_robot

    assert "pprs6" in available_robots()
    robot = load_robot("pprs6")
    assert robot.drive_names == ("w1", "w2", "beta", "s1", "s2", "s3")
    assert robot.drive_units == ("m", "m", "rad", "m", "m", "m")
    with pytest.raises(InvalidInput):
        load_robot("pprs6", rail_length=2.0)
