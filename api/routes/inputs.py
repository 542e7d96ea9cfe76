"""What every submission route checks of its document before it queues a job.

* :func:`stored_meshes`: the mesh names a document gives (``cabin.mesh``, ``payload.mesh``,
  ``unit.mesh`` ...) are reference cabins or ids of the tenant's uploads in the units the document says;
  the answer maps each upload id to its file on this instance;
* :func:`check_time_limit`: a planning time limit within the service's ceiling;
* :func:`empty_dir`: the base folder documents resolve against (empty: the service reads no user files).

Each failure is a 422 problem naming the field.
"""

from __future__ import annotations

from pathlib import Path

from api.context import AppContext
from api.problems import Problem
from planner.meshes import reference_cabin_path, reference_cabins

#: ``(field, mesh name, units, may be a reference cabin)`` of one mesh a document names.
MeshField = tuple[str, str, str, bool]


def stored_meshes(ctx: AppContext, tenant: str, fields: list[MeshField]) -> dict[str, str]:
    """Stored files of the tenant's meshes named by ``fields`` (id -> path); 422 naming the field otherwise.

    A name that may be a reference cabin and is one is left out (the planner finds it); any other name
    must be the id of an upload of this tenant, uploaded in the units the document gives.
    """
    meshes: dict[str, str] = {}
    for field, name, units, cabin in fields:
        if cabin and reference_cabin_path(name) is not None:
            continue
        row = ctx.store.get(tenant, name)
        if row is None:
            hint = f" nor a reference cabin ({', '.join(reference_cabins())})" if cabin else ""
            raise Problem(
                422,
                "invalid_input",
                f"{field}: {name!r} is neither the id of an uploaded mesh of this tenant{hint}",
                errors=[{"field": field, "reason": "unknown mesh"}],
            )
        if row.units != units:
            units_field = field.removesuffix(".mesh") + ".units"
            raise Problem(
                422,
                "invalid_input",
                f"{units_field}: the mesh {name[:12]}... was uploaded in {row.units!r}, the document says "
                f"{units!r}",
                errors=[{"field": units_field, "reason": f"must be {row.units!r} for this mesh"}],
            )
        meshes[name] = str(ctx.store.local_path(row))
    return meshes


def check_time_limit(ctx: AppContext, time_limit_s: float) -> None:
    """422 naming ``options.time_limit_s`` when it exceeds the service's ceiling [s]."""
    ceiling = ctx.settings.time_limit_ceiling_s
    if time_limit_s > ceiling:
        raise Problem(
            422,
            "invalid_input",
            f"options.time_limit_s: {time_limit_s} s exceeds the service's ceiling of {ceiling} s",
            errors=[{"field": "options.time_limit_s", "reason": f"must be at most {ceiling}"}],
        )


def empty_dir(ctx: AppContext) -> Path:
    """The empty folder documents resolve relative paths against (created)."""
    empty = ctx.settings.data_dir / "empty"
    empty.mkdir(parents=True, exist_ok=True)
    return empty
