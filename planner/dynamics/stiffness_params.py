"""The stiffness model's unknown data as a parameter vector (issue 15), chosen by the fit and calibration.

Parameters (names used in fits, reports and calibration files):

* ``k.<drive>``: the stiffness of drive ``<drive>`` (``d1 x1 x2 x3 theta3 theta4 d5 theta6``) [N/m] or
  [N m/rad];
* ``s.<link>``: the section scale of link ``<link>`` (``link_ab link_cd link_ef platform column arm
  slide``): both sides b and h of its rectangle multiplied by the same factor (aspect kept), so the area
  scales by s^2 and the second moments by s^4;
* ``pin``: the translational compliance of every stage pin [m/N] (``pin_compliance_m_N``).

A fit works on ``theta = log(p / p_ref)`` (every parameter is positive and acts multiplicatively, so
relative changes are the natural unit and the Jacobian columns are comparable); a *variable* may move
several parameters together (e.g. the three identical sliders). ``p_ref`` is the base description's value
(for ``pin`` with a rigid base pin, :data:`PIN_REFERENCE_M_N`). Section scales are relative to the base
description's sections, so ``s.*`` of a base description is 1.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.core.description import HYBRID8_DRIVES, LinkSections, Section, StiffnessSpec
from planner.core.exceptions import InvalidInput

Array = NDArray[np.float64]

LINKS: tuple[str, ...] = tuple(LinkSections.model_fields)
PARAMETERS: tuple[str, ...] = (
    *(f"k.{d}" for d in HYBRID8_DRIVES),
    *(f"s.{link}" for link in LINKS),
    "pin",
)
#: Reference pin compliance [m/N] when the base description's pins are rigid (1 um per kN: a preloaded
#: bearing pair of about 1e9 N/m).
PIN_REFERENCE_M_N = 1e-9


def parameter_unit(name: str) -> str:
    """Unit of a parameter's value."""
    if name == "pin":
        return "m/N"
    if name.startswith("s."):
        return "1"
    return "N m/rad" if name.removeprefix("k.").startswith("theta") else "N/m"


def check_names(names: Sequence[str], field: str = "parameters") -> tuple[str, ...]:
    """Validate parameter names (every one known, no repeats).

    Raises:
        InvalidInput: an unknown or repeated name (``details['field']`` = ``field``).
    """
    unknown = [n for n in names if n not in PARAMETERS]
    if unknown:
        raise InvalidInput(
            f"{field}: unknown stiffness parameters {unknown}; known: {', '.join(PARAMETERS)}", field=field
        )
    if len(set(names)) != len(names):
        raise InvalidInput(f"{field}: repeated parameter names {list(names)}", field=field)
    if not names:
        raise InvalidInput(f"{field}: no parameter to fit", field=field)
    return tuple(names)


def reference_values(base: StiffnessSpec) -> dict[str, float]:
    """``p_ref`` of every parameter for a base description (see the module docstring)."""
    out = {f"k.{d}": float(base.drives[d]) for d in HYBRID8_DRIVES}
    out |= {f"s.{link}": 1.0 for link in LINKS}
    out["pin"] = base.pin_compliance_m_N if base.pin_compliance_m_N > 0 else PIN_REFERENCE_M_N
    return out


def current_values(base: StiffnessSpec) -> dict[str, float]:
    """The base description's own value of every parameter (``pin`` may be 0: a rigid pin)."""
    return reference_values(base) | {"pin": base.pin_compliance_m_N}


@dataclass(frozen=True)
class ParameterSet:
    """A fit's variables over a base description: each variable scales a group of parameters together.

    Attributes:
        base: The description's stiffness data the variables are relative to.
        groups: One tuple of parameter names per variable.
    """

    base: StiffnessSpec
    groups: tuple[tuple[str, ...], ...]

    @classmethod
    def of(cls, base: StiffnessSpec, groups: Sequence[Sequence[str] | str]) -> ParameterSet:
        """Variables from names (one parameter each) or tuples of names (scaled together)."""
        gs = tuple((g,) if isinstance(g, str) else tuple(g) for g in groups)
        check_names([n for g in gs for n in g])
        return cls(base, gs)

    @property
    def labels(self) -> tuple[str, ...]:
        """One label per variable: its names joined by '+'."""
        return tuple("+".join(g) for g in self.groups)

    def spec(self, theta: Array, **extra: object) -> StiffnessSpec:
        """The stiffness data at ``theta`` (log multipliers of the reference values, one per variable)."""
        values = current_values(self.base)
        ref = reference_values(self.base)
        for g, t in zip(self.groups, np.asarray(theta, dtype=float), strict=True):
            for name in g:
                values[name] = ref[name] * math.exp(float(t))
        return with_values(self.base, values, **extra)

    def theta_of(self, spec: StiffnessSpec) -> Array:
        """Log multipliers of a spec's values (each group's first parameter) relative to the reference."""
        values, ref = current_values(spec), reference_values(self.base)
        sizes = section_scales(self.base, spec)
        out = []
        for g in self.groups:
            v = sizes[g[0]] if g[0].startswith("s.") else values[g[0]]
            out.append(math.log(max(v, 1e-300) / ref[g[0]]))
        return np.array(out)


def section_scales(base: StiffnessSpec, spec: StiffnessSpec) -> dict[str, float]:
    """``s.<link>`` of ``spec`` relative to ``base`` (the ratio of the h sides)."""
    return {f"s.{link}": getattr(spec.sections, link).h / getattr(base.sections, link).h for link in LINKS}


def with_values(base: StiffnessSpec, values: Mapping[str, float], **extra: object) -> StiffnessSpec:
    """``base`` with parameters replaced (``k.*`` absolute, ``s.*`` scales of base's sections, ``pin``).

    ``extra`` replaces other fields of the spec (``source``, ``note``, ``uncertainty``).
    """
    drives = {d: float(values.get(f"k.{d}", base.drives[d])) for d in HYBRID8_DRIVES}
    sections = {}
    for link in LINKS:
        sec: Section = getattr(base.sections, link)
        s = float(values.get(f"s.{link}", 1.0))
        sections[link] = Section(b=sec.b * s, h=sec.h * s)
    return base.model_copy(
        update={
            "drives": drives,
            "sections": LinkSections(**sections),
            "pin_compliance_m_N": float(values.get("pin", base.pin_compliance_m_N)),
            **extra,
        }
    )


def stiffness_yaml_block(spec: StiffnessSpec, comment: Sequence[str] = ()) -> str:
    """The ``stiffness:`` section of a description file for ``spec`` (top-level key, two-space indent)."""
    lines = ["stiffness:"]
    lines += [f"  # {c}" if c else "  #" for c in comment]
    lines += [
        f"  source: {spec.source}",
        f"  E_Pa: {spec.E_Pa:.6g}",
        f"  G_Pa: {spec.G_Pa:.6g}",
        f"  pin_compliance_m_N: {spec.pin_compliance_m_N:.4g}",
        "  sections:",
    ]
    for link in LINKS:
        sec = getattr(spec.sections, link)
        lines.append(f"    {link}: [{sec.b:.4g}, {sec.h:.4g}]")
    lines.append("  drives:           # N/m for prismatic drives, N m/rad for revolute ones")
    lines += [f"    {d}: {spec.drives[d]:.4g}" for d in HYBRID8_DRIVES]
    if spec.uncertainty:
        lines.append("  uncertainty:      # relative standard deviation of each fitted parameter")
        lines += [f"    {k}: {v:.4g}" for k, v in spec.uncertainty.items()]
    if spec.note:
        lines.append(f"  note: {_yaml_str(spec.note)}")
    return "\n".join(lines) + "\n"


def _yaml_str(text: str) -> str:
    import json

    return json.dumps(text)  # a JSON string is a valid YAML flow scalar
