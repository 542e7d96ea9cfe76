"""pprs6: the 2PPRS-RPRS 6-DOF parallel platform as a :class:`~planner.robots.base.RobotModel`.

Coordinates (SI):

* drives ``u = (w1, w2, beta, s1, s2, s3)`` (m, m, rad, m, m, m): the chain-1/2 sliders along their
  supports, the chain-3 revolute, and the three second prismatic joints;
* "joints" are the platform pose ``x = (x, y, z, phi, theta, psi)`` of the centre O1 in the fixed frame
  with ``R = RotZ(phi) RotY(theta) RotX(psi)`` (paper eq. 5). The drive map ``u = IK(x)`` is closed form,
  the inverse map is the Newton forward kinematics (:mod:`planner.kinematics.pprs6`, where the paper
  readings are documented).

The description file (``pprs6.yaml``) is validated on load (errors name the field) and hashed for
provenance, like cabin8's.
"""

from __future__ import annotations

import hashlib
import math
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from planner.core.description import DriveSpec, jerk_limits, load_description_file
from planner.core.exceptions import InvalidInput, OutsideWorkspace
from planner.core.timing_names import default_timing
from planner.core.types import Array, BoolArray
from planner.kinematics import pprs6 as kin
from planner.robots.base import DriveLimits, RobotModel


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Pprs6GeometrySpec(_Frozen):
    """Geometry block of the description (paper Table 1) [m], [rad]."""

    platform_radius: float = Field(gt=0, description="r, circumradius of the platform triangle [m]")
    base_radius: float = Field(gt=0, description="R, distance O B3 [m]")
    link_lengths: tuple[float, float, float] = Field(description="D_i C_i of chains 1..3 [m]")
    support_angles: tuple[float, float, float] = Field(description="directions of O B_i [rad]")

    @model_validator(mode="after")
    def _positive(self) -> Pprs6GeometrySpec:
        if not all(v > 0 and math.isfinite(v) for v in self.link_lengths):
            raise ValueError(f"link_lengths must be positive, got {list(self.link_lengths)}")
        return self


class ChainSpec(_Frozen):
    """One chain: its joint types from the base to the platform."""

    name: str
    joints: tuple[Literal["P", "R", "S"], ...]


class Pprs6Description(_Frozen):
    """Description of a 2PPRS-RPRS platform (``kind: pprs6``)."""

    name: str
    kind: Literal["pprs6"]
    description: str
    geometry: Pprs6GeometrySpec
    chains: tuple[ChainSpec, ChainSpec, ChainSpec]
    drives: tuple[DriveSpec, ...]
    home: dict[str, float]
    sample_period_s: float = Field(gt=0, le=0.1)

    @model_validator(mode="after")
    def _structure(self) -> Pprs6Description:
        names = tuple(d.name for d in self.drives)
        if names != kin.DRIVES:
            raise ValueError(f"drives must be {list(kin.DRIVES)} in this order, got {list(names)}")
        kinds = tuple(d.kind for d in self.drives)
        expected = ("prismatic", "prismatic", "revolute", "prismatic", "prismatic", "prismatic")
        if kinds != expected:
            raise ValueError(f"drive kinds must be {list(expected)}, got {list(kinds)}")
        types = tuple("".join(c.joints) for c in self.chains)
        if types != ("PPRS", "PPRS", "RPRS"):
            raise ValueError(f"chains must be PPRS, PPRS, RPRS (the model's kinematics), got {list(types)}")
        if set(self.home) != set(kin.POSE):
            raise ValueError(f"home must give every pose coordinate {list(kin.POSE)}")
        jerk_limits(self.drives)
        return self


def load_pprs6_description(path: Path) -> Pprs6Description:
    """Load and validate a pprs6 description file.

    Raises:
        InvalidRobotDescription: missing file, not YAML, or a schema failure (the message names the field).
    """
    return load_description_file(path, Pprs6Description)


def default_description_path() -> Path:
    """Path of the packaged pprs6 description file."""
    return Path(str(resources.files("planner.robots").joinpath("pprs6.yaml")))


@cache
def _load(path: str) -> tuple[Pprs6Description, str]:
    p = Path(path)
    desc = load_pprs6_description(p)
    return desc, hashlib.sha256(p.read_bytes()).hexdigest()


#: Human-readable name of each drive's limit owner.
_CHAIN_OF_DRIVE = ("chain1", "chain2", "chain3", "chain1", "chain2", "chain3")


#: Step in the path parameter of the central difference of the drive Jacobian along a path.
_FD_STEP = 1e-4


class Pprs6(RobotModel):
    """The 2PPRS-RPRS platform: limits, closed-form IK, Newton FK, Jacobians, mobility.

    Args:
        description: Path of a ``kind: pprs6`` description file (default: the packaged pprs6).
    """

    kind = "pprs6"

    def __init__(self, description: Path | None = None) -> None:
        path = (description or default_description_path()).resolve()
        desc, sha = _load(str(path))
        self.desc = desc
        self.description_sha256 = sha
        g = desc.geometry
        self.geometry = kin.Pprs6Geometry(
            r=g.platform_radius, R=g.base_radius, L=g.link_lengths, support_angles=g.support_angles
        )
        self.name = desc.name
        self.drive_names = kin.DRIVES
        self.drive_units = tuple(d.unit for d in desc.drives)
        self.joint_names = kin.POSE
        self.joint_units = ("m", "m", "m", "rad", "rad", "rad")
        self.limits = DriveLimits(
            lower=np.array([d.lower for d in desc.drives]),
            upper=np.array([d.upper for d in desc.drives]),
            v_max=np.array([d.v_max for d in desc.drives]),
            a_max=np.array([d.a_max for d in desc.drives]),
            effort_max=np.array([d.effort_max for d in desc.drives]),
            j_max=jerk_limits(desc.drives),
        )
        self.sample_period_s = desc.sample_period_s
        self.home_pose = np.array([desc.home[n] for n in kin.POSE])
        self.home_pose.setflags(write=False)
        self.chains: list[list[str]] = [list(c.joints) for c in desc.chains]

    # ------------------------------------------------------------------ inverse
    def inverse(self, poses: Array) -> kin.InverseResult:
        """Unchecked closed-form IK of poses (N, 6): drives (NaN where a chain cannot close) and flags."""
        return kin.inverse(self.geometry, np.atleast_2d(np.asarray(poses, dtype=float)))

    def within_limits(self, drives: Array, tol: float = 1e-12) -> BoolArray:
        """(N, 6) bool: each drive within its range (NaN counts as outside)."""
        u = np.atleast_2d(drives)
        with np.errstate(invalid="ignore"):
            return (u >= self.limits.lower - tol) & (u <= self.limits.upper + tol)

    def admissible(self, poses: Array) -> BoolArray:
        """(N,) bool: every chain closes and every drive is within its range (paper eq. 15)."""
        inv = self.inverse(poses)
        return np.asarray(inv.reachable.all(axis=1) & self.within_limits(inv.drives).all(axis=1))

    def ik(self, poses: Array) -> Array:
        """Closed-form inverse kinematics, poses (N, 6) -> drives (N, 6), or (6,) -> (6,).

        Raises:
            OutsideWorkspace: a chain cannot close (``condition`` ``chain_cannot_close``) or a drive
                leaves its range (``condition`` ``drive_range``); details name the chain, the drive, the
                value and the limit, and the first failing ``index``.
        """
        x = np.asarray(poses, dtype=float)
        single = x.ndim == 1
        x2 = np.atleast_2d(x)
        if x2.shape[1] != 6 or not np.all(np.isfinite(x2)):
            raise InvalidInput("pose: expected finite poses of shape (N, 6)", field="pose")
        inv = self.inverse(x2)
        bad_chain = ~inv.reachable
        if bad_chain.any():
            i, c = (int(v) for v in np.argwhere(bad_chain)[0])
            raise OutsideWorkspace(
                f"pose {i}: chain {c + 1} cannot close (its link cannot reach the sphere centre C{c + 1})",
                condition="chain_cannot_close",
                chain=f"chain{c + 1}",
                index=i,
            )
        self._raise_outside_ranges(inv.drives)
        return inv.drives[0] if single else inv.drives

    def _raise_outside_ranges(self, u: Array) -> None:
        ok = self.within_limits(u)
        if ok.all():
            return
        i, j = (int(v) for v in np.argwhere(~ok)[0])
        lo, hi = self.limits.lower[j], self.limits.upper[j]
        side, limit = ("lower", lo) if u[i, j] < lo else ("upper", hi)
        raise OutsideWorkspace(
            f"pose {i}: drive {self.drive_names[j]} ({_CHAIN_OF_DRIVE[j]}) = {u[i, j]:.6g} "
            f"{self.drive_units[j]} is outside its range [{lo:.6g}, {hi:.6g}]",
            condition="drive_range",
            chain=_CHAIN_OF_DRIVE[j],
            drive=self.drive_names[j],
            value=float(u[i, j]),
            limit=float(limit),
            side=side,
            index=i,
        )

    # ------------------------------------------------------------------ forward
    def fk(self, drives: Array, guess: Array | None = None) -> Array:
        """Forward kinematics (Newton on the closure equations), drives (N, 6) -> poses (N, 6) or (6,).

        Newton starts from ``guess`` ((6,) or (N, 6), e.g. a nearby known pose) when given, then from the
        home pose, then from the level-platform estimate of the drives; it returns the first solution on
        the working branch. The forward problem has several solutions (e.g. near-mirror yaws on either
        side of the level-platform singularity): the one returned is the one connected to the start, so
        a caller tracking a motion should pass the previous pose.

        Raises:
            OutsideWorkspace: a drive is outside its range.
            ForwardKinematicsFailed: Newton converged from no start (no assembly, or too far away).
        """
        u = np.asarray(drives, dtype=float)
        single = u.ndim == 1
        u2 = np.atleast_2d(u)
        if u2.shape[1] != 6 or not np.all(np.isfinite(u2)):
            raise InvalidInput("drives: expected finite drive vectors of shape (N, 6)", field="drives")
        self._raise_outside_ranges(u2)
        guesses: list[Array] = [] if guess is None else [np.asarray(guess, dtype=float)]
        guesses += [self.home_pose, kin.level_guess(self.geometry, u2)]
        x = kin.forward_or_raise(self.geometry, u2, guesses)
        return x[0] if single else x

    # ------------------------------------------------------------------ RobotModel
    def drives_from_joints(self, q: Array) -> Array:
        """Drives for platform poses (the closed-form IK); raises OutsideWorkspace."""
        return self.ik(q)

    def joints_from_drives(self, u: Array) -> Array:
        """Platform poses for drives (the Newton FK from the default starts)."""
        return self.fk(u)

    def drive_path(self, q: Array, dq: Array, ddq: Array) -> tuple[Array, Array, Array]:
        """u, u', u'' of a pose path (N, 6) each: u = IK(x), u' = J x', u'' = J x'' + (dJ/ds) x'.

        dJ/ds = (J(x + h x') - J(x - h x')) / 2h with h = 1e-4 (a central difference of the analytic
        Jacobian along the path, an O(1e-8) relative error); raises OutsideWorkspace off the workspace.
        """
        x = np.atleast_2d(np.asarray(q, dtype=float))
        dx = np.atleast_2d(np.asarray(dq, dtype=float))
        ddx = np.atleast_2d(np.asarray(ddq, dtype=float))
        u = kin.inverse(self.geometry, x).drives
        J = kin.drive_jacobian(self.geometry, x)
        J_p = kin.drive_jacobian(self.geometry, x + _FD_STEP * dx)
        J_m = kin.drive_jacobian(self.geometry, x - _FD_STEP * dx)
        du = np.einsum("nij,nj->ni", J, dx)
        ddu = np.einsum("nij,nj->ni", J, ddx) + np.einsum("nij,nj->ni", J_p - J_m, dx) / (2.0 * _FD_STEP)
        return u, du, ddu

    # ------------------------------------------------------------------ Jacobians, mobility
    def drive_jacobian(self, poses: Array) -> Array:
        """Analytic J = du/dx, (N, 6) -> (N, 6, 6) or (6,) -> (6, 6) (Euler-angle rates)."""
        x = np.asarray(poses, dtype=float)
        J = kin.drive_jacobian(self.geometry, np.atleast_2d(x))
        return J[0] if x.ndim == 1 else J

    def condition_number(self, poses: Array) -> Array:
        """Singularity measure: condition number of the homogenised drive Jacobian, (N,) (inf: no IK)."""
        x = np.atleast_2d(np.asarray(poses, dtype=float))
        return kin.scaled_condition_number(self.geometry, kin.drive_jacobian(self.geometry, x))

    def grubler(self) -> dict[str, int]:
        """Kutzbach-Grübler count (paper eq. 4) from the description's joint list."""
        return kin.grubler(self.chains)

    def mobility(self, pose: Array) -> dict[str, Any]:
        """Numerical mobility at one pose: ranks of the loop-closure and closure Jacobians.

        Returns:
            {"loop_rank", "loop_unknowns", "mobility" (= unknowns - loop rank), "chain_ranks" (rank of
            each chain's twist system; 6 means no constraint screw, as the paper's screw analysis says),
            "closure_rank_pose" (rank of dPhi/dx), "closure_rank_drives" (rank of dPhi/dq)}.
        """
        x = np.asarray(pose, dtype=float)
        u = self.inverse(x).drives[0]
        A = kin.loop_jacobian(self.geometry, u, x)
        _, dx, dq = kin.closure(self.geometry, u, x)
        return {
            "loop_rank": kin.numerical_rank(A),
            "loop_unknowns": A.shape[1],
            "mobility": A.shape[1] - kin.numerical_rank(A),
            "chain_ranks": [kin.numerical_rank(T) for T in kin.chain_twists(self.geometry, u, x)],
            "closure_rank_pose": kin.numerical_rank(dx[0]),
            "closure_rank_drives": kin.numerical_rank(dq[0]),
        }

    # ------------------------------------------------------------------ summary
    def pose_dict(self, x: Array) -> dict[str, float]:
        """Name -> value mapping of one pose."""
        return {n: float(v) for n, v in zip(kin.POSE, np.asarray(x, dtype=float), strict=True)}

    def summary(self) -> dict[str, Any]:
        """JSON-serialisable model summary: drives, units, limits, geometry, chains, mobility count."""
        lim = self.limits
        g = self.geometry
        return {
            "name": self.name,
            "kind": self.kind,
            "description": self.desc.description,
            "description_sha256": self.description_sha256,
            "drives": [
                {
                    "name": n,
                    "unit": un,
                    "lower": float(lo),
                    "upper": float(hi),
                    "v_max": float(v),
                    "a_max": float(a),
                    "effort_max": float(f),
                    "j_max": d.j_max,
                }
                for n, un, lo, hi, v, a, f, d in zip(
                    self.drive_names,
                    self.drive_units,
                    lim.lower,
                    lim.upper,
                    lim.v_max,
                    lim.a_max,
                    lim.effort_max,
                    self.desc.drives,
                    strict=True,
                )
            ],
            "pose": {"names": list(kin.POSE), "units": list(self.joint_units)},
            "geometry": {
                "platform_radius_m": g.r,
                "base_radius_m": g.R,
                "link_lengths_m": list(g.L),
                "support_angles_rad": list(g.support_angles),
                "rotation": "RotZ(phi) RotY(theta) RotX(psi)",
            },
            "chains": [{"name": c.name, "joints": "".join(c.joints)} for c in self.desc.chains],
            "grubler": self.grubler(),
            "home": self.pose_dict(self.home_pose),
            "sample_period_s": self.sample_period_s,
            "default_timing": default_timing(lim.j_max is not None),
        }
