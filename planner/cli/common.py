"""What every ``cabinplan`` command shares: the typer app, exit codes, errors, files, progress bars."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import wraps
from pathlib import Path
from typing import Annotated, Any, NoReturn, ParamSpec, Self, TypeVar

import typer
from pydantic import ValidationError

from planner.core.exceptions import (
    GoalUnreachable,
    InvalidInput,
    LimitViolation,
    OutsideWorkspace,
    PlannerError,
    PlanRefused,
)
from planner.robots import available_robots, load_robot
from planner.robots.cabin8 import Cabin8

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="cabinplan: cabin robot planning tools",
)

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
        except (typer.Exit, typer.Abort):
            raise
        except Exception as exc:  # a bug, not the user's fault: one line, never a traceback
            _fail(f"internal_error: {type(exc).__name__}: {exc}", 1)

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


RobotArg = Annotated[str, typer.Argument(help=f"robot model ({', '.join(available_robots())})")]


ScenarioArg = Annotated[
    Path, typer.Argument(help="scenario file (.yaml, .yml or .json)", exists=False, dir_okay=False)
]


def _load(scenario: Path) -> Any:
    from planner.scenario.resolve import load_scenario

    return load_scenario(scenario)


def _write(path: Path, data: str | bytes, what: str) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, bytes):
            path.write_bytes(data)
        else:
            path.write_text(data, encoding="utf-8")
    except OSError as exc:
        _fail(f"{what}: cannot write {path} ({exc.strerror})", 1)


@contextmanager
def refusal_to(output: Path, refusal: Callable[[PlannerError], dict[str, Any]]) -> Iterator[None]:
    """A planning command's refusals: the refusal document to --output, one line, the exit code.

    A refusal (no admissible answer) exits 3, any other planner failure 1, each after writing
    ``refusal(exc)`` to ``output`` so that --output never holds a stale profile; invalid input goes on to
    :func:`handle_errors` (exit 2, nothing written).
    """
    try:
        yield
    except InvalidInput:
        raise
    except PlannerError as exc:
        _write(output, json.dumps(refusal(exc), indent=1) + "\n", "--output")
        infeasible = isinstance(exc, PlanRefused | GoalUnreachable | OutsideWorkspace | LimitViolation)
        _fail(f"{exc.reason}: {exc.message}", EXIT_INFEASIBLE if infeasible else 1)


class _Bar:
    """A rich progress bar on stderr (``bar``), or nothing (None) when stderr is not a terminal."""

    bar: Any = None

    def __enter__(self) -> Self:
        if self.bar is not None:
            self.bar.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.stop()


class _Progress(_Bar):
    """Stage progress on stderr when it is a terminal (rich), silent otherwise."""

    def __init__(self, enabled: bool) -> None:
        if enabled:
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(
                TextColumn("{task.description:<12}"), BarColumn(), TimeElapsedColumn(), transient=True
            )
            self.task = self.bar.add_task("planning", total=1.0)

    def __call__(self, stage: str, fraction: float) -> None:
        if self.bar is not None:
            self.bar.update(self.task, completed=fraction, description=stage)
