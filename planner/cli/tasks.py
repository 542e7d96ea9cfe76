"""The ``cabinplan`` commands of many plans: an assembly cycle, a feasibility sweep, a campaign."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from planner.cli.common import EXIT_INFEASIBLE, _Bar, _fail, _Progress, _write, app, handle_errors, refusal_to


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
    from planner.documents.cycle import cycle_document, cycle_png, cycle_refusal_document
    from planner.documents.output import clearance_phrase, document_bytes
    from planner.task.cycle import plan_cycle
    from planner.task.resolve import load_cycle

    cyc = load_cycle(cycle_file)
    with (
        refusal_to(output, lambda exc: cycle_refusal_document(exc, cyc)),
        _Progress(sys.stderr.isatty()) as progress,
    ):
        result = plan_cycle(cyc, progress)
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
