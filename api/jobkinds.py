"""Job kinds: what the service can run as a job, one entry each (plans, assembly cycles, campaigns).

Every kind shares the job machinery of :mod:`api.jobstore` (queue, tenants and their quota, idempotency,
leases, cancellation, retention, progress) and the HTTP helpers of :mod:`api.routes.jobroutes`. A kind
only says what differs:

* ``name``: stored in the job's ``kind`` column (rows without one are plans: they predate kinds);
* ``collection``: its URL collection under ``/api/v1`` (``plans`` -> ``/api/v1/plans/{id}``) and
  ``noun``, the word its messages use ("no plan 'x'");
* ``input_key``: the key of the job document naming what was submitted (``scenario``: its name and
  SHA-256, read from the job's provenance as ``<input_key>_sha256``);
* ``runner``: ``function(job, progress) -> outcome`` run in the job's worker process (see
  :func:`api.worker.plan_job`; sent to the worker with the job, pickled by reference); the job modules
  import the planner inside their functions, so this registry imports nothing heavy;
* ``files``: the downloads made from a succeeded job's result document, on request
  (:class:`ResultFile`): nothing but the document is written on the worker's critical path.

A new kind is one :func:`register` call beside the module that implements it, plus its routes (thin
calls into :mod:`api.routes.jobroutes`).
"""

from __future__ import annotations

from api import cycles, worker
from api.jobtypes import DEFAULT_KIND, FileSource, JobKind, ResultFile

_KINDS: dict[str, JobKind] = {}


def register(kind: JobKind) -> JobKind:
    """Add ``kind`` to the registry (its name and collection must be new); returns it.

    Raises:
        ValueError: a kind of that name or collection is registered already.
    """
    for other in _KINDS.values():
        if kind.name == other.name or kind.collection == other.collection:
            raise ValueError(f"job kind {kind.name!r} ({kind.collection}) clashes with {other.name!r}")
    _KINDS[kind.name] = kind
    return kind


def kind_of(name: str | None) -> JobKind:
    """The kind called ``name`` (``None``: a row that predates kinds, a plan).

    Raises:
        KeyError: no such kind.
    """
    return _KINDS[name or DEFAULT_KIND]


def kinds() -> tuple[JobKind, ...]:
    """Every registered kind, in registration order."""
    return tuple(_KINDS.values())


#: Planning jobs: a scenario in, a drive profile (or a refusal) out; the CSV and the plot on request.
PLAN = register(
    JobKind(
        name="plan",
        collection="plans",
        noun="plan",
        runner=worker.plan_job,
        files=(
            ResultFile("profile.csv", "profile_csv", "text/csv; charset=utf-8", worker.profile_csv),
            ResultFile("plot.png", "plot_png", "image/png", worker.plot_png, stored=True),
        ),
    )
)


#: Assembly cycles: a cycle document in, one cycle profile document (legs, events) or a refusal out.
CYCLE = register(
    JobKind(
        name="cycle",
        collection="cycles",
        noun="cycle",
        runner=cycles.cycle_job,
        input_key="cycle",
        files=(
            ResultFile("profile.csv", "profile_csv", "text/csv; charset=utf-8", cycles.cycle_profile_csv),
            ResultFile("plot.png", "plot_png", "image/png", cycles.cycle_plot_png, stored=True),
        ),
    )
)

#: Campaigns: units installed one cycle each in a cabin that fills up; the summary and the cycle documents.
CAMPAIGN = register(
    JobKind(
        name="campaign",
        collection="campaigns",
        noun="campaign",
        runner=cycles.campaign_job,
        input_key="campaign",
        files=(
            ResultFile("profile.csv", "profile_csv", "text/csv; charset=utf-8", cycles.campaign_profile_csv),
            ResultFile("units.csv", "units_csv", "text/csv; charset=utf-8", cycles.campaign_units_csv),
            ResultFile("plot.png", "plot_png", "image/png", cycles.campaign_plot_png, stored=True),
        ),
    )
)


__all__ = [
    "CAMPAIGN",
    "CYCLE",
    "DEFAULT_KIND",
    "PLAN",
    "FileSource",
    "JobKind",
    "ResultFile",
    "kind_of",
    "kinds",
    "register",
]
