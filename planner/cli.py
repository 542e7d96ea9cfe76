"""The ``cabinplan`` command line: thin typer commands that parse, call one planner function, and print.

Output is JSON on stdout. On failure exactly one readable line goes to stderr and the exit code tells the
kind: 2 invalid input, 3 no admissible answer (unreachable pose, outside the workspace), 1 anything else.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable
from functools import wraps
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn, ParamSpec, Self, TypeVar

import typer
from pydantic import ValidationError

from planner.core.exceptions import (
    GoalUnreachable,
    InvalidInput,
    LimitViolation,
    OutsideWorkspace,
    PlannerError,
)
from planner.robots import available_robots, load_robot
from planner.robots.cabin8 import Cabin8
from planner.scenario import MAX_SEED
from planner.tools import kinematics_tools

if TYPE_CHECKING:
    pass

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
    guess: Annotated[
        str | None, typer.Option(help="pprs6: JSON pose to start from (the assembly mode connected to it)")
    ] = None,
) -> None:
    """Forward kinematics: drives (or joints) -> joints, drives and T_base_tool (row-major 4x4)."""
    tools = kinematics_tools(robot)
    doc = tools.fk(
        robot,
        None if drives is None else _json_arg(drives, "--drives"),
        None if joints is None else _json_arg(joints, "--joints"),
        None if guess is None else _json_arg(guess, "--guess"),
    )
    _emit(doc)
    if doc.get("warning"):  # several assembly modes (pprs6): say so where a person reads it too
        typer.echo(f"cabinplan: warning: {doc['warning']}", err=True)


@app.command()
@handle_errors
def ik(
    robot: RobotArg,
    pose: Annotated[
        str, typer.Option(help='JSON: {"position": [x, y, z], "orientation": {"w","x","y","z"}}')
    ],
    near: Annotated[str | None, typer.Option(help="JSON drives: return the solution nearest these")] = None,
    seed: Annotated[int, typer.Option(help="seed of the random restarts", min=0, max=MAX_SEED)] = 0,
) -> None:
    """Inverse kinematics of a tool pose (base frame): one admissible solution, or exit 3 if unreachable."""
    tools = kinematics_tools(robot)
    near_drives = None if near is None else _json_arg(near, "--near")
    _emit(tools.ik(robot, _json_arg(pose, "--pose"), near_drives, seed))


@app.command()
@handle_errors
def stiffness(
    robot: RobotArg,
    drives: Annotated[str | None, typer.Option(help="JSON object: drive name -> position [m, rad]")] = None,
    joints: Annotated[str | None, typer.Option(help="JSON object: joint name -> value [m, rad]")] = None,
    wrench: Annotated[
        str | None,
        typer.Option(help='JSON wrench at the frame origin: [fx,fy,fz,mx,my,mz] or {"force","moment"}'),
    ] = None,
    payload: Annotated[
        str | None, typer.Option(help='JSON payload: {"mass", "com"?, "inertia"? or "box"?, "grasp"?}')
    ] = None,
    frame: Annotated[str, typer.Option(help="tool | payload: where K, C and deflections are given")] = "tool",
    measurements: Annotated[
        Path | None, typer.Argument(help="calibrate: the measurements CSV", dir_okay=False)
    ] = None,
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="calibrate: the calibrated description (YAML)")
    ] = None,
    description: Annotated[
        Path | None, typer.Option(help="calibrate: base description (default: the packaged cabin8)")
    ] = None,
    parameters: Annotated[
        str | None, typer.Option(help="calibrate: comma-separated parameters to fit (default: drives, pin)")
    ] = None,
    sigma_m: Annotated[float, typer.Option(help="calibrate: translation noise [m]")] = 1e-5,
    sigma_rad: Annotated[float, typer.Option(help="calibrate: rotation noise [rad]")] = 1e-5,
) -> None:
    """Cartesian stiffness K, compliance C and static deflection (gravity, a wrench) at a configuration.

    ``cabinplan stiffness calibrate MEASUREMENTS.csv -o calibrated.yaml`` instead fits the stiffness data
    to measured deflections and writes a description the planner can use (scenario ``robot_description``).
    """
    from planner.documents.stiffness import stiffness_document

    if robot == "calibrate":
        from planner.documents.calibration import calibrate_file

        if measurements is None or output is None:
            _fail("stiffness calibrate: give MEASUREMENTS.csv and -o OUTPUT.yaml", EXIT_INVALID)
        names = None if parameters is None else [p.strip() for p in parameters.split(",") if p.strip()]
        _emit(calibrate_file(measurements, output, description, names, sigma_m, sigma_rad))
        return
    if measurements is not None:
        _fail(f"stiffness: unexpected argument {str(measurements)!r} (only 'calibrate' takes a file)", 2)
    if (drives is None) == (joints is None):
        _fail("stiffness: give exactly one of --drives or --joints", EXIT_INVALID)
    _emit(
        stiffness_document(
            robot,
            drives=None if drives is None else _json_arg(drives, "--drives"),
            joints=None if joints is None else _json_arg(joints, "--joints"),
            wrench=None if wrench is None else _json_arg(wrench, "--wrench"),
            payload=None if payload is None else _json_arg(payload, "--payload"),
            frame=frame,
        )
    )


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


@app.command()
@handle_errors
def plan(
    scenario: ScenarioArg,
    output: Annotated[Path, typer.Option("-o", "--output", help="drive profile / refusal JSON")],
    csv: Annotated[Path | None, typer.Option("--csv", help="also write the profile as CSV")] = None,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="also plot profiles and clearance (PNG)")
    ] = None,
) -> None:
    """Plan a scenario: a validated drive profile (exit 0), or a refusal with its reason (exit 3).

    The JSON written to --output is the profile on success and the refusal document otherwise.
    """
    from planner.core.exceptions import PlanRefused
    from planner.documents.output import clearance_phrase, document_bytes, refusal_document, result_document
    from planner.plan.pipeline import Planner

    sc = _load(scenario)
    try:
        with _Progress(sys.stderr.isatty()) as progress:
            planner = Planner(sc, progress)
            result = planner.plan()
    except (PlanRefused, GoalUnreachable, OutsideWorkspace, LimitViolation) as exc:
        _write(output, json.dumps(refusal_document(exc, sc), indent=1) + "\n", "--output")
        _fail(f"{exc.reason}: {exc.message}", EXIT_INFEASIBLE)
    except InvalidInput:
        raise
    except PlannerError as exc:  # any other failure still leaves its reason in --output, never a stale file
        _write(output, json.dumps(refusal_document(exc, sc), indent=1) + "\n", "--output")
        _fail(f"{exc.reason}: {exc.message}", 1)
    _write(output, document_bytes(result_document(sc, result, arrays=True)) + b"\n", "--output")
    if csv is not None:
        _write(csv, result.profile.to_csv(), "--csv")
    if plot is not None:
        from planner.documents.plot import plan_png

        _write(plot, plan_png(sc, result, planner.world), "--plot")
    typer.echo(
        f"cabinplan: {sc.spec.name}: succeeded, {result.profile.duration_s:.3f} s, "
        f"{len(result.profile.t)} samples, {clearance_phrase(result.gate)} -> {output}",
        err=True,
    )


@app.command()
@handle_errors
def cycle(
    cycle_file: Annotated[
        Path, typer.Argument(metavar="FILE", help="cycle file (.yaml, .yml or .json)", dir_okay=False)
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="cycle profile / refusal JSON")],
    csv: Annotated[Path | None, typer.Option("--csv", help="also write the profile as CSV")] = None,
    plot: Annotated[Path | None, typer.Option("--plot", help="also plot the profile (PNG)")] = None,
) -> None:
    """Plan an assembly cycle.

    one certified drive profile with its legs and events (exit 0), or a refusal with its reason and the leg
    that refused (exit 3).

    The JSON written to --output is the cycle profile on success and the refusal document otherwise.
    """
    from planner.core.exceptions import PlanRefused
    from planner.documents.cycle import cycle_document, cycle_png, cycle_refusal_document
    from planner.documents.output import clearance_phrase, document_bytes
    from planner.task.cycle import plan_cycle
    from planner.task.resolve import load_cycle

    cyc = load_cycle(cycle_file)
    try:
        with _Progress(sys.stderr.isatty()) as progress:
            result = plan_cycle(cyc, progress)
    except (PlanRefused, GoalUnreachable, OutsideWorkspace, LimitViolation) as exc:
        _write(output, json.dumps(cycle_refusal_document(exc, cyc), indent=1) + "\n", "--output")
        _fail(f"{exc.reason}: {exc.message}", EXIT_INFEASIBLE)
    except InvalidInput:
        raise
    except PlannerError as exc:
        _write(output, json.dumps(cycle_refusal_document(exc, cyc), indent=1) + "\n", "--output")
        _fail(f"{exc.reason}: {exc.message}", 1)
    _write(output, document_bytes(cycle_document(cyc, result, arrays=True)) + b"\n", "--output")
    if csv is not None:
        _write(csv, result.profile.to_csv(), "--csv")
    if plot is not None:
        _write(plot, cycle_png(cyc, result), "--plot")
    springs = ", ".join(f"{e.kind} {1e3 * e.springback_m:.2f} mm" for e in result.events)
    typer.echo(
        f"cabinplan: {cyc.spec.name}: succeeded, {result.profile.duration_s:.3f} s, {len(result.profile.t)} "
        f"samples, {len(result.legs)} legs, {clearance_phrase(result.gate)}, "
        f"spring-back {springs} -> {output}",
        err=True,
    )


class _SweepProgress(_Bar):
    """Sweep progress on stderr when it is a terminal (rich: done / failed / running, ETA)."""

    def __init__(self, enabled: bool, total: int) -> None:
        if enabled:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(
                TextColumn("sweep"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn(
                    "ok {task.fields[ok]}  failed {task.fields[failed]}  running {task.fields[running]}"
                ),
                TextColumn("ETA"),
                TimeRemainingColumn(),
            )
            self.task = self.bar.add_task("sweep", total=total, ok=0, failed=0, running=0)

    def __call__(self, counts: Any) -> None:
        if self.bar is not None:
            self.bar.update(
                self.task,
                completed=counts.done,
                ok=counts.succeeded,
                failed=counts.failed,
                running=counts.running,
            )


@app.command()
@handle_errors
def sweep(
    spec: Annotated[Path, typer.Argument(help="sweep description (.yaml, .yml or .json)", dir_okay=False)],
    output: Annotated[Path, typer.Option("-o", "--output", help="output folder (results, plots, profiles)")],
    workers: Annotated[
        int, typer.Option("--workers", min=1, max=256, help="plans at a time (local processes or Ray CPUs)")
    ] = max(1, os.cpu_count() or 1),
    ray: Annotated[
        bool, typer.Option("--ray", envvar="CABINPLAN_SWEEP_RAY", help="run plans as Ray tasks")
    ] = False,
    ray_address: Annotated[
        str | None,
        typer.Option("--ray-address", help="Ray cluster address (default RAY_ADDRESS, else a local Ray)"),
    ] = None,
    max_in_flight: Annotated[
        int | None, typer.Option("--max-in-flight", min=1, help="Ray: most tasks submitted at a time")
    ] = None,
    plans_per_process: Annotated[
        int | None,
        typer.Option(
            "--plans-per-process",
            min=0,
            help="embedded: plans one worker process runs before it is replaced "
            "(default 200; 0: no limit; 1: a fresh process per plan). A plan past its limit is killed "
            "either way.",
        ),
    ] = None,
    plots: Annotated[bool, typer.Option("--plots/--no-plots", help="write the summary plots")] = True,
) -> None:
    """Run a feasibility sweep: every plan of SPEC, results.csv / results.parquet, plots and profiles.

    Resumable: plans that already have a row in OUTPUT (keyed by scenario hash) are skipped.
    """
    from planner.sweep.expand import expand_sweep
    from planner.sweep.plots import write_plots
    from planner.sweep.results import Journal, write_tables
    from planner.sweep.run import (
        DEFAULT_PLANS_PER_PROCESS,
        EmbeddedExecutor,
        RayExecutor,
        run_sweep,
        sweep_meshes,
        warm_task,
    )
    from planner.sweep.spec import load_sweep_file

    sw = load_sweep_file(spec)
    plans = expand_sweep(sw, spec.parent)
    journal = Journal(output)
    todo = [p for p in plans if not journal.done(p.sha256)]
    executor: Any = None
    try:
        if todo:
            warm = warm_task(todo)
            if ray:
                executor = RayExecutor(ray_address, workers, max_in_flight, sweep_meshes(todo), warm)
            else:
                ppp = DEFAULT_PLANS_PER_PROCESS if plans_per_process is None else plans_per_process
                executor = EmbeddedExecutor(workers, warm, ppp)
            with _SweepProgress(sys.stderr.isatty(), len(plans)) as progress:
                run_sweep(plans, output, executor, sw.limits, progress=progress)
        else:  # every plan has a row (e.g. killed after the last one): the tables are written anyway
            for plan in plans:
                journal.write_scenario(plan)
            write_tables(output, journal.table(plans))
    except KeyboardInterrupt:
        _fail(f"sweep {sw.name}: interrupted; the rows so far are in {output}, rerun to resume", 130)
    finally:
        if executor is not None:
            executor.close()
    rows = Journal(output).table(plans)
    if plots:
        write_plots(output, rows)
    ok = sum(1 for r in rows if r["status"] == "succeeded")
    reasons: dict[str, int] = {}
    for r in rows:
        if r["status"] != "succeeded":
            reasons[str(r["reason"])] = reasons.get(str(r["reason"]), 0) + 1
    why = ", ".join(f"{k} {v}" for k, v in sorted(reasons.items()))
    skipped = len(plans) - len(todo)
    typer.echo(
        f"cabinplan: sweep {sw.name}: {len(rows)} of {len(plans)} plans, {ok} succeeded, "
        f"{len(rows) - ok} failed{f' ({why})' if why else ''}, {skipped} already done -> {output}",
        err=True,
    )


@app.command()
@handle_errors
def export(
    plan_document: Annotated[
        Path,
        typer.Argument(
            help="a succeeded plan or cycle document (JSON, as written by `plan`)", dir_okay=False
        ),
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="goal file, or the bag folder for mcap")],
    fmt: Annotated[
        str,
        typer.Option("--format", help="ros2-json | ros2-yaml (FollowJointTrajectory goal) | mcap (rosbag2)"),
    ] = "ros2-yaml",
    spacing_s: Annotated[
        float | None,
        typer.Option(
            "--spacing-s", help="thin the trajectory points to this spacing [s] (default: every sample)"
        ),
    ] = None,
    scenario: Annotated[
        Path | None,
        typer.Option("--scenario", help="mcap: the plan's scenario, for the exact clearance along the plan"),
    ] = None,
) -> None:
    """Export a plan for a controller or a tool: a FollowJointTrajectory goal (JSON/YAML) or a rosbag2 MCAP.

    Thinning keeps every sample within 1e-5 (m or rad) and the drive limits under the controller's quintic
    interpolation, adding points where it must. Exit 2 for a document that is not a succeeded plan.
    """
    from planner.documents import exports

    if fmt not in exports.FORMATS:
        _fail(f"--format: must be one of {', '.join(exports.FORMATS)}, got {fmt!r}", EXIT_INVALID)
    try:
        doc = json.loads(plan_document.read_text(encoding="utf-8"))
    except OSError as exc:
        _fail(f"plan: cannot read {plan_document} ({exc.strerror})", EXIT_INVALID)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        _fail(f"plan: {plan_document} is not a JSON document ({exc})", EXIT_INVALID)
    if not isinstance(doc, dict):
        _fail(f"plan: {plan_document} is not a plan document (a JSON object)", EXIT_INVALID)
    if fmt == "mcap":
        if output.exists():
            _fail(f"--output: {output} exists; a rosbag2 bag is a new folder", EXIT_INVALID)
        exports.profile_of(doc)  # refuse a bad document before anything is computed or written
        clearance = exports.clearance_series(_load(scenario), doc) if scenario is not None else None
        exports.write_rosbag(doc, output, spacing_s=spacing_s, clearance=clearance)
        size = sum(p.stat().st_size for p in output.iterdir())
    else:
        data, _ = exports.export_bytes(doc, fmt, spacing_s=spacing_s)
        _write(output, data, "--output")
        size = len(data)
    typer.echo(f"cabinplan: export {fmt}: {size} bytes -> {output}")


@app.command()
@handle_errors
def check(
    scenario: ScenarioArg,
    profile: Annotated[
        Path, typer.Argument(help="drive profile JSON (as written by `plan`)", dir_okay=False)
    ],
) -> None:
    """Run the validation gate on a drive profile for a scenario; the report goes to stdout.

    A cycle profile (``kind: cycle``) is checked against its cycle file instead.

    Exit 0 when every check passes, 3 when any fails.
    """
    from planner.gate.check_profile import check_profile

    try:
        data = json.loads(profile.read_text(encoding="utf-8"))
    except OSError as exc:
        _fail(f"profile: cannot read {profile} ({exc.strerror})", EXIT_INVALID)
    except json.JSONDecodeError as exc:
        _fail(f"profile: not valid JSON ({exc.msg} at line {exc.lineno})", EXIT_INVALID)
    except UnicodeDecodeError:
        _fail(f"profile: {profile} is not UTF-8 text (expected the JSON written by plan)", EXIT_INVALID)
    if isinstance(data, dict) and data.get("kind") == "cycle":
        from planner.task.check import check_cycle
        from planner.task.resolve import load_cycle

        report = check_cycle(load_cycle(scenario), data)
    else:
        report = check_profile(_load(scenario), data)
    _emit(report.to_dict())
    if not report.passed:
        _fail(f"validation_failed: {report.summary()}", EXIT_INFEASIBLE)


@app.command()
@handle_errors
def workspace(
    robot: RobotArg,
    orientation: Annotated[
        str | None, typer.Option(help='JSON {"phi","theta","psi"} [rad] (default: level)')
    ] = None,
    step: Annotated[float, typer.Option("--step", help="grid step [m]")] = 0.005,
    png: Annotated[Path | None, typer.Option("--png", help="also write the three views (PNG)")] = None,
) -> None:
    """Reachable platform positions at a fixed orientation (boundary search): volume, extents, views."""
    if robot != "pprs6":
        load_robot(robot)
        _fail(f"workspace: not available for robot {robot!r} (pprs6 only)", EXIT_INVALID)
    from planner.tools import pprs6 as pprs6_tools

    doc, image = pprs6_tools.workspace_document(
        None if orientation is None else _json_arg(orientation, "--orientation"),
        step_m=step,
        png=png is not None,
    )
    if png is not None:
        _write(png, image, "--png")
    _emit(doc)


@app.command()
@handle_errors
def profile(
    robot: RobotArg,
    path: Annotated[
        Path | None, typer.Argument(help="pose-path file (YAML/JSON); default: the paper's path")
    ] = None,
    output: Annotated[Path | None, typer.Option("-o", "--output", help="drive profile JSON")] = None,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="also plot the drive displacements (PNG)")
    ] = None,
) -> None:
    """Pose path -> validated drive profile (timed under the drive limits), or exit 3 with the reason."""
    if robot != "pprs6":
        load_robot(robot)
        _fail(
            f"profile: not available for robot {robot!r} (pprs6 only; cabin8 plans scenarios)", EXIT_INVALID
        )
    import yaml

    from planner.core.exceptions import PlanRefused
    from planner.tools import pprs6 as pprs6_tools

    spec = None
    if path is not None:
        try:
            spec = yaml.safe_load(path.read_text(encoding="utf-8"))
        except OSError as exc:
            _fail(f"path: cannot read {path} ({exc.strerror})", EXIT_INVALID)
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            _fail(f"path: {path} is not YAML/JSON ({type(exc).__name__})", EXIT_INVALID)
    try:
        doc = pprs6_tools.profile_document(spec)
    except PlanRefused as exc:
        _fail(f"{exc.reason}: {exc.message}", EXIT_INFEASIBLE)
    text = json.dumps(doc) + "\n"
    if output is None:
        sys.stdout.write(text)
    else:
        _write(output, text, "--output")
    if plot is not None:
        _write(plot, pprs6_tools.profile_png(doc), "--plot")
    typer.echo(
        f"cabinplan: pprs6 {doc['path']['name']}: succeeded, {doc['duration_s']:.3f} s, "
        f"{len(doc['t'])} samples",
        err=True,
    )


@app.command()
@handle_errors
def generate(
    out: Annotated[Path, typer.Option("-o", "--out", help="folder for the scenario and mesh files")],
    count: Annotated[int, typer.Option(min=1, max=10000, help="number of scenarios")] = 10,
    seed: Annotated[int, typer.Option(min=0, help="seed: the same seed gives the same files")] = 0,
    start: Annotated[int, typer.Option(min=0, help="index of the first case")] = 0,
    clearance: Annotated[
        float, typer.Option("--clearance-m", min=0.001, max=0.2, help="requested clearance [m]")
    ] = 0.01,
    rail_length: Annotated[
        float, typer.Option("--rail-length-m", min=3.0, max=6.0, help="rail length [m] (shorter cabins)")
    ] = 6.0,
    family: Annotated[
        str,
        typer.Option(
            help="family of cabins: mixed, ring-frame, octagonal, box-section, stringer, end-bay, cluttered"
        ),
    ] = "mixed",
) -> None:
    """Generate seeded, reproducible cabins and scenarios (YAML + mesh files) that `plan` runs as they are."""
    from planner.generate import FAMILIES, GeneratorOptions, generate_case, write_case, write_manifest

    if family not in FAMILIES:
        raise InvalidInput(f"family: must be one of {', '.join(FAMILIES)}, got {family!r}", field="family")
    options = GeneratorOptions(clearance_m=clearance, rail_length_m=rail_length, family=family)
    cases = []
    for index in range(start, start + count):
        case = generate_case(seed, index, options)
        path = write_case(case, out)
        typer.echo(
            f"cabinplan: {path} ({case.meta['goal']}, {case.meta['format']} in {case.meta['units']})",
            err=True,
        )
        cases.append(case)
    write_manifest(cases, out, seed)
    _emit({"out": str(out), "seed": seed, "scenarios": [f"{c.name}.yaml" for c in cases]})


class _CampaignProgress(_Bar):
    """Campaign progress on stderr when it is a terminal: one row per unit (status, cycles planned)."""

    def __init__(self, enabled: bool, units: list[str]) -> None:
        self.tasks: dict[str, Any] = {}
        if enabled:
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(
                TextColumn("{task.description:<12}"),
                BarColumn(bar_width=20),
                TextColumn("{task.fields[status]:<11} cycles {task.fields[cycles]}"),
                TimeElapsedColumn(),
            )
            for u in units:
                self.tasks[u] = self.bar.add_task(u, total=1, status="waiting", cycles=0)

    def __call__(self, status: dict[str, Any]) -> None:
        if self.bar is None:
            return
        for u, st in status.items():
            done = st.status in ("planned", "refused", "not_planned")
            self.bar.update(
                self.tasks[u],
                completed=1 if done else 0,
                status=st.status,
                cycles=st.cycles_planned + st.cycles_cached,
            )


@app.command()
@handle_errors
def campaign(
    spec: Annotated[Path, typer.Argument(help="campaign file (.yaml, .yml or .json)", dir_okay=False)],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="output folder (cycle documents, summary.json)")
    ],
    workers: Annotated[
        int, typer.Option("--workers", min=1, max=256, help="cycles at a time (local processes or Ray CPUs)")
    ] = max(1, os.cpu_count() or 1),
    ray: Annotated[bool, typer.Option("--ray", help="run the cycles as Ray tasks")] = False,
    ray_address: Annotated[
        str | None,
        typer.Option("--ray-address", help="Ray cluster address (default RAY_ADDRESS, else a local Ray)"),
    ] = None,
) -> None:
    """Install a campaign's units one cycle at a time: the cycle documents in install order + summary.json.

    Resumable: cycles with a row in OUTPUT's journal (keyed by the cycle's hash) are not planned again.
    Exit 0 when every unit is installed, 3 when a cycle is refused (given order) or no order is found.
    """
    from planner.campaign.run import CYCLE_RUNNER, CampaignRun, campaign_meshes
    from planner.sweep.run import WARMUP_TIME_LIMIT_S, EmbeddedExecutor, RayExecutor
    from planner.task.campaign import check_campaign
    from planner.task.campaign_schema import load_campaign_file

    camp = load_campaign_file(spec)
    base_dir = spec.parent.resolve()
    check_campaign(camp, base_dir)
    executor: Any = None
    try:
        with _CampaignProgress(sys.stderr.isatty(), camp.ids) as progress:
            run = CampaignRun(camp, output, None, base_dir=base_dir, progress=progress)
            first = run.job(camp.ids[0], ())
            warm: dict[str, Any] | None = None
            if not run.journal.done(first.sha256):  # something to plan: warm the workers on it
                warm = {"runner": CYCLE_RUNNER, "cycle": first.document, "base_dir": str(base_dir)}
                warm["cycle"] = {**warm["cycle"], "options": {**warm["cycle"]["options"]}}
                limit = warm["cycle"]["options"].get("time_limit_s", 30.0)
                warm["cycle"]["options"]["time_limit_s"] = min(float(limit), WARMUP_TIME_LIMIT_S)
            if ray:
                executor = RayExecutor(ray_address, workers, None, campaign_meshes(camp, base_dir), warm)
            else:
                executor = EmbeddedExecutor(workers, warm)
            run.executor = executor
            result = run.run()
    except KeyboardInterrupt:
        _fail(f"campaign {camp.name}: interrupted; the cycles so far are in {output}, rerun to resume", 130)
    finally:
        if executor is not None:
            executor.close()
    total = sum(e["duration_s"] or 0.0 for e in result.units if e["status"] == "planned")
    typer.echo(
        f"cabinplan: campaign {camp.name}: {result.message}; {len(result.order)} units in order "
        f"{' '.join(result.order) or '-'}, campaign {total:.1f} s; {result.cycles_planned} cycles planned, "
        f"{result.cycles_cached} already done -> {output}",
        err=True,
    )
    if not result.succeeded:
        raise typer.Exit(EXIT_INFEASIBLE)


def main() -> None:
    """Console-script entry point.

    OMPL's Python bindings print reference-leak warnings at interpreter exit; after a command that loaded
    OMPL the process ends with ``os._exit`` once its output is flushed, so stderr keeps its one line.
    """
    import click

    try:
        rv = app(standalone_mode=False)
        code = rv if isinstance(rv, int) else 0
    except click.exceptions.Exit as exc:
        code = exc.exit_code
    except click.ClickException as exc:
        exc.show()
        code = exc.exit_code
    except click.Abort:
        typer.echo("cabinplan: aborted", err=True)
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    if "ompl" in sys.modules:
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    main()
