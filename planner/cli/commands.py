"""The ``cabinplan`` commands of single plans and tools.

robot, fk, ik, stiffness, plan, export, check, the pprs6 workspace and profile, generate.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from planner.cli.common import (
    EXIT_INFEASIBLE,
    EXIT_INVALID,
    RobotArg,
    ScenarioArg,
    _emit,
    _fail,
    _json_arg,
    _load,
    _Progress,
    _write,
    app,
    handle_errors,
    refusal_to,
)
from planner.core.exceptions import InvalidInput
from planner.core.startup import loading_modules
from planner.robots import load_robot
from planner.scenario import MAX_SEED
from planner.tools import kinematics_tools


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
    with loading_modules():
        from planner.documents.output import (
            clearance_phrase,
            document_bytes,
            refusal_document,
            result_document,
        )
        from planner.plan.pipeline import Planner

    sc = _load(scenario)
    with (
        refusal_to(output, lambda exc: refusal_document(exc, sc)),
        _Progress(sys.stderr.isatty()) as progress,
    ):
        planner = Planner(sc, progress)
        result = planner.plan()
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
