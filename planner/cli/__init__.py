"""The ``cabinplan`` command line: thin typer commands that parse, call one planner function, and print.

Output is JSON on stdout. On failure exactly one readable line goes to stderr and the exit code tells the
kind: 2 invalid input, 3 no admissible answer (unreachable pose, outside the workspace), 1 anything else.
"""

from __future__ import annotations

import os
import sys

from planner.core.startup import loading_modules, tune_allocator

tune_allocator()  # the gate's and the search's large temporaries from the heap (see its docstring)
with loading_modules(freeze=True):  # the command line's modules, without the collector's passes
    import typer

    from planner.cli import commands, tasks  # noqa: F401 - the commands register with the app on import
    from planner.cli.common import app

__all__ = ["app", "main"]


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
