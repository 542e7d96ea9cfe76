"""The ``cabinplan`` command line: thin typer commands that parse, call one planner function, and print.

Output is JSON on stdout. On failure exactly one readable line goes to stderr and the exit code tells the
kind: 2 invalid input, 3 no admissible answer (unreachable pose, outside the workspace), 1 anything else.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from functools import wraps
from typing import Annotated, Any, NoReturn, ParamSpec, TypeVar

import numpy as np
import typer
from pydantic import ValidationError

from planner.exceptions import (
    GoalUnreachable,
    InvalidInput,
    LimitViolation,
    OutsideWorkspace,
    PlannerError,
)
from planner.robots import available_robots, load_robot
from planner.robots.cabin8 import Cabin8
from planner.schemas import Pose

app = typer.Typer(add_completion=False, no_args_is_help=True, help="cabinplan: cabin robot planning tools")

EXIT_INVALID = 2
EXIT_INFEASIBLE = 3

P = ParamSpec("P")
R = TypeVar("R")


def _fail(message: str, code: int) -> NoReturn:
    typer.echo(f"cabinplan: {message}", err=True)
    raise typer.Exit(code)


def _readable(exc: ValidationError, what: str) -> str:
    first = exc.errors()[0]
    where = ".".join(str(p) for p in first["loc"])
    return f"{what}{'.' + where if where else ''}: {first['msg']}"


def handle_errors(fn: Callable[P, R]) -> Callable[P, R]:
    """Map planner errors to one stderr line and the documented exit codes."""

    @wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        try:
            return fn(*args, **kwargs)
        except (GoalUnreachable, OutsideWorkspace, LimitViolation) as exc:
            _fail(f"{exc.reason}: {exc.message}", EXIT_INFEASIBLE)
        except InvalidInput as exc:
            _fail(f"{exc.reason}: {exc.message}", EXIT_INVALID)
        except PlannerError as exc:
            _fail(f"{exc.reason}: {exc.message}", 1)

    return wrapper


def _json_arg(text: str, option: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        _fail(f"{option}: not valid JSON ({exc.msg} at column {exc.colno})", EXIT_INVALID)


def _emit(payload: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(payload, indent=2) + "\n")


def _cabin8(robot: str) -> Cabin8:
    model = load_robot(robot)
    if not isinstance(model, Cabin8):
        _fail(f"robot {robot!r} has no tool-pose kinematics in this command", EXIT_INVALID)
    return model


def _pose_json(T: np.ndarray) -> dict[str, Any]:
    pose = Pose.from_matrix(T)
    return {"position": list(pose.position), "orientation": pose.orientation.model_dump()}


RobotArg = Annotated[str, typer.Argument(help=f"robot model ({', '.join(available_robots())})")]


@app.command()
@handle_errors
def robot(name: RobotArg) -> None:
    """Print the robot model summary: drives, units, limits, geometry."""
    _emit(load_robot(name).summary())


@app.command()
@handle_errors
def fk(
    robot: RobotArg,
    drives: Annotated[str | None, typer.Option(help="JSON object: drive name -> position [m, rad]")] = None,
    joints: Annotated[str | None, typer.Option(help="JSON object: joint name -> value [m, rad]")] = None,
) -> None:
    """Forward kinematics: drives (or joints) -> joints, drives and T_base_tool (row-major 4x4)."""
    model = _cabin8(robot)
    if (drives is None) == (joints is None):
        _fail("fk: give exactly one of --drives or --joints", EXIT_INVALID)
    if drives is not None:
        u = model.drives_from_dict(_json_arg(drives, "--drives"), field="drives")
        q = model.joints_from_drives(u)
    else:
        q = model.joints_from_dict(_json_arg(joints or "", "--joints"), field="joints")
        u = model.drives_from_joints(q)
    T = model.fk(q)
    _emit(
        {
            "robot": model.name,
            "joints": model.joints_dict(q),
            "drives": model.drives_dict(u),
            "T_base_tool": [float(v) for v in T.reshape(-1)],
            "pose": _pose_json(T),
            "violations": model.violations(q),
        }
    )


@app.command()
@handle_errors
def ik(
    robot: RobotArg,
    pose: Annotated[
        str, typer.Option(help='JSON: {"position": [x, y, z], "orientation": {"w","x","y","z"}}')
    ],
    near: Annotated[str | None, typer.Option(help="JSON drives: return the solution nearest these")] = None,
    seed: Annotated[int, typer.Option(help="seed of the random restarts")] = 0,
) -> None:
    """Inverse kinematics of a tool pose (base frame): one admissible solution, or exit 3 if unreachable."""
    from planner.redundancy.ik import IKOptions, solve_pose_ik

    model = _cabin8(robot)
    try:
        target = Pose.model_validate(_json_arg(pose, "--pose"))
    except ValidationError as exc:
        _fail(_readable(exc, "pose"), EXIT_INVALID)
    near_u = None if near is None else model.drives_from_dict(_json_arg(near, "--near"), field="near")
    sol = solve_pose_ik(model, target.matrix(), near_drives=near_u, options=IKOptions(seed=seed))
    T = model.fk(sol.q)
    _emit(
        {
            "robot": model.name,
            "drives": model.drives_dict(sol.u),
            "joints": model.joints_dict(sol.q),
            "T_base_tool": [float(v) for v in T.reshape(-1)],
            "position_error_m": sol.position_error_m,
            "orientation_error_rad": sol.orientation_error_rad,
            "min_margin": sol.min_margin,
            "iterations": sol.iterations,
        }
    )


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()
