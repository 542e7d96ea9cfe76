"""Robot description files: the pydantic schema and the loader.

A description is a YAML file in SI units (m, rad, s, kg, N, N·m). It is validated once on load; the
resulting objects are immutable and are what the kinematics, dynamics and limits are built from.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from functools import cached_property
from pathlib import Path
from typing import Literal, TypeVar

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from planner.core.exceptions import InvalidRobotDescription
from planner.core.types import Array

DescriptionT = TypeVar("DescriptionT", bound=BaseModel)


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class DriveSpec(_Frozen):
    """One actuated drive: position range and rate, acceleration and effort limits (SI)."""

    name: str
    kind: Literal["prismatic", "revolute"]
    lower: float = Field(description="lower position limit [m] or [rad]")
    upper: float = Field(description="upper position limit [m] or [rad]")
    v_max: float = Field(gt=0, description="speed limit [m/s] or [rad/s]")
    a_max: float = Field(gt=0, description="acceleration limit [m/s^2] or [rad/s^2]")
    effort_max: float = Field(gt=0, description="force [N] or torque [N m] limit")
    j_max: float | None = Field(
        None, gt=0, allow_inf_nan=False, description="jerk limit [m/s^3] or [rad/s^3] (optional)"
    )

    @model_validator(mode="after")
    def _ordered(self) -> DriveSpec:
        if not self.lower < self.upper:
            raise ValueError(f"drive {self.name}: lower {self.lower} must be below upper {self.upper}")
        return self

    @property
    def unit(self) -> str:
        """Position unit of the drive."""
        return "m" if self.kind == "prismatic" else "rad"


def jerk_limits(drives: tuple[DriveSpec, ...]) -> Array | None:
    """Jerk limits in drive order (n_drives,), or None when the description gives none.

    Raises:
        ValueError: some drives have a jerk limit and others not (a partial set cannot bound the jerk).
    """
    given = [d.j_max is not None for d in drives]
    if not any(given):
        return None
    if not all(given):
        missing = [d.name for d in drives if d.j_max is None]
        raise ValueError(f"j_max must be given for every drive or for none; missing for {missing}")
    return np.array([float(d.j_max) for d in drives if d.j_max is not None])


class ParallelStageSpec(_Frozen):
    """Planar PRR/PR(PRR)R stage geometry and admissibility margins (paper Fig. 5)."""

    L1: float = Field(gt=0, description="AB [m]")
    L2: float = Field(gt=0, description="BC, the platform [m]")
    L3: float = Field(gt=0, description="CD [m]")
    L4: float = Field(gt=0, description="EF, E the midpoint of AB [m]")
    min_slider_gap: float = Field(ge=0, description="x3-x1 and x2-x3 lower bound [m]")
    y_range: tuple[float, float] = Field(description="platform centre height range [m]")
    gamma_max: float = Field(gt=0, lt=math.pi / 2, description="|gamma| bound [rad]")
    min_sin_cbd: float = Field(gt=0, lt=1, description="lower bound of sin(angle CBD)")
    max_link_height_ratio: float = Field(gt=0, lt=1, description="y_B/L1, y_C/L3, y_B/(2 L4) bound")

    @model_validator(mode="after")
    def _consistent(self) -> ParallelStageSpec:
        lo, hi = self.y_range
        if not 0 < lo < hi:
            raise ValueError(f"y_range {self.y_range} must satisfy 0 < lower < upper")
        return self


class MDHSpec(_Frozen):
    """One link of Craig's modified DH: RotX(alpha) TransX(a) RotZ(theta) TransZ(d)."""

    alpha: float
    a: float
    theta: float
    d: float
    variable: str = Field(description="joint that replaces theta (revolute) or d (prismatic)")


class Masses(_Frozen):
    """Link masses [kg]; links are uniform slender bodies between their joint centres."""

    carriage: float = Field(ge=0)
    platform: float = Field(ge=0)
    link_ab: float = Field(ge=0)
    link_cd: float = Field(ge=0)
    link_ef: float = Field(ge=0)
    column: float = Field(ge=0)
    arm: float = Field(ge=0)
    slide: float = Field(ge=0)
    tool: float = Field(ge=0)


#: Drive order of a hybrid8 description (also the keys of its drive stiffnesses).
HYBRID8_DRIVES = ("d1", "x1", "x2", "x3", "theta3", "theta4", "d5", "theta6")


class Section(_Frozen):
    """Solid rectangular cross-section b x h [m], b >= h (b along the link's local z axis)."""

    b: float = Field(gt=0, description="width along the link's local z axis [m]")
    h: float = Field(gt=0, description="depth in the link's bending plane (local y) [m]")

    @model_validator(mode="before")
    @classmethod
    def _from_pair(cls, value: object) -> object:
        if isinstance(value, list | tuple):
            if len(value) != 2:
                raise ValueError(f"a section is [b, h] in m, got {value}")
            return {"b": value[0], "h": value[1]}
        return value

    @model_validator(mode="after")
    def _wide(self) -> Section:
        if self.b < self.h:
            raise ValueError(f"section [b, h] = [{self.b}, {self.h}] needs b >= h (paper eq. 54's I_p)")
        return self


class LinkSections(_Frozen):
    """Cross-sections of every flexible link (paper section 4: rectangular flexible beams)."""

    link_ab: Section
    link_cd: Section
    link_ef: Section
    platform: Section
    column: Section
    arm: Section
    slide: Section


#: Where a description's stiffness data come from (issue 15). Deflection compensation is on by default
#: only for the two trustworthy ones (:data:`TRUSTED_STIFFNESS_SOURCES`).
StiffnessSource = Literal["paper-fit", "calibrated", "nominal"]
TRUSTED_STIFFNESS_SOURCES: frozenset[str] = frozenset({"paper-fit", "calibrated"})


class StiffnessSpec(_Frozen):
    """Material, link sections, drive and pin stiffnesses of the stiffness model (issues 7 and 15).

    ``source`` says where the numbers come from: ``paper-fit`` (chosen by ``python -m
    planner.dynamics.paper_fit`` to reproduce the paper's Table 2), ``calibrated`` (fitted to a cell's
    measurements by ``cabinplan stiffness calibrate``) or ``nominal`` (guesses; the default for a
    description that does not say). ``pin_compliance_m_N`` is the translational compliance of each stage
    pin (A-F) along each base axis (bearing play-free radial/axial compliance); 0 is a rigid pin.
    ``uncertainty`` (calibrated data) holds each fitted parameter's relative standard deviation.
    """

    E_Pa: float = Field(gt=0, description="Young's modulus [Pa]")
    G_Pa: float = Field(gt=0, description="shear modulus [Pa]")
    sections: LinkSections
    drives: dict[str, float] = Field(description="drive stiffness [N/m] or [N m/rad] by drive name")
    pin_compliance_m_N: float = Field(0.0, ge=0, lt=1e-3, description="stage pin compliance [m/N]")
    source: StiffnessSource = Field("nominal", description="where the stiffness data come from")
    note: str = Field("", max_length=4000, description="how the data were obtained (free text)")
    uncertainty: dict[str, float] | None = Field(
        None, description="relative standard deviation of each fitted parameter (calibrated data)"
    )

    @model_validator(mode="after")
    def _drives(self) -> StiffnessSpec:
        if set(self.drives) != set(HYBRID8_DRIVES):
            raise ValueError(
                f"drives must give every drive {list(HYBRID8_DRIVES)}, got {sorted(self.drives)}"
            )
        bad = {k: v for k, v in self.drives.items() if not (math.isfinite(v) and v > 0)}
        if bad:
            raise ValueError(f"drive stiffnesses must be finite and > 0, got {bad}")
        return self

    def drive_stiffness(self) -> Array:
        """Drive stiffnesses in drive order, shape (8,) [N/m] or [N m/rad]."""
        return np.array([self.drives[n] for n in HYBRID8_DRIVES])


class Hybrid8Description(_Frozen):
    """Description of a hybrid rail + planar parallel stage + serial arm robot (``kind: hybrid8``)."""

    name: str
    kind: Literal["hybrid8"]
    description: str
    gravity_m_s2: tuple[float, float, float]
    joints: tuple[str, ...]
    drives: tuple[DriveSpec, ...]
    parallel_stage: ParallelStageSpec
    serial_chain: tuple[MDHSpec, ...]
    masses: Masses
    home: dict[str, float]
    stiffness: StiffnessSpec | None = None

    @model_validator(mode="after")
    def _structure(self) -> Hybrid8Description:
        expected_joints = ("d1", "x", "y", "gamma", "theta3", "theta4", "d5", "theta6")
        expected_drives = ("d1", "x1", "x2", "x3", "theta3", "theta4", "d5", "theta6")
        if self.joints != expected_joints:
            raise ValueError(f"joints must be {list(expected_joints)}, got {list(self.joints)}")
        names = tuple(d.name for d in self.drives)
        if names != expected_drives:
            raise ValueError(f"drives must be {list(expected_drives)} in this order, got {list(names)}")
        variables = tuple(link.variable for link in self.serial_chain)
        if variables != expected_joints[4:]:
            raise ValueError(f"serial_chain variables must be {list(expected_joints[4:])}, got {variables}")
        if set(self.home) != set(expected_drives):
            raise ValueError(f"home must give every drive {list(expected_drives)}")
        jerk_limits(self.drives)
        return self

    @property
    def drive_names(self) -> tuple[str, ...]:
        """Drive names in drive order."""
        return tuple(d.name for d in self.drives)

    @cached_property
    def lower(self) -> Array:
        """Lower drive position limits, shape (8,)."""
        return np.array([d.lower for d in self.drives])

    @cached_property
    def upper(self) -> Array:
        """Upper drive position limits, shape (8,)."""
        return np.array([d.upper for d in self.drives])


def description_hash(path: Path) -> str:
    """SHA-256 of a description file's bytes (for plan provenance)."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def load_description_file(path: Path, model: type[DescriptionT]) -> DescriptionT:
    """Load a YAML description file and validate it with the pydantic ``model`` (any robot's schema).

    Raises:
        InvalidRobotDescription: the file is missing, not YAML, or fails the schema (the message names
            the field and the reason).
    """
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise InvalidRobotDescription(f"cannot read robot description {path}: {exc}", path=str(path)) from exc
    if not isinstance(raw, Mapping):
        raise InvalidRobotDescription(f"robot description {path} is not a mapping", path=str(path))
    try:
        return model.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "<root>"
        raise InvalidRobotDescription(
            f"robot description {path.name}: {where}: {first['msg']}", path=str(path), field=where
        ) from exc


def load_description(path: Path) -> Hybrid8Description:
    """Load and validate a cabin8-type (hybrid 8-DOF) description file (see :func:`load_description_file`)."""
    return load_description_file(path, Hybrid8Description)
