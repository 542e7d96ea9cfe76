"""Job kinds: what the service can run as a job, one entry each (plans, assembly cycles, campaigns).

Every kind shares the job machinery of :mod:`api.jobstore` (queue, tenants and their quota, idempotency,
leases, cancellation, retention, progress) and the HTTP helpers of :mod:`api.routes.jobroutes`. A kind
only says what differs:

* ``name``: stored in the job's ``kind`` column (rows without one are plans: they predate kinds);
* ``collection``: its URL collection under ``/api/v1`` (``plans`` -> ``/api/v1/plans/{id}``) and
  ``noun``, the word its messages use ("no plan 'x'");
* ``input_key``: the key of the job document naming what was submitted (``scenario``: its name and
  SHA-256, read from the job's provenance as ``<input_key>_sha256``);
* ``runner``: ``"module:function"`` run in the job's worker process, ``function(job, progress) ->
  outcome`` (see :func:`api.worker.plan_job`); imported there by name, so this registry imports nothing
  heavy;
* ``files``: the downloads made from a succeeded job's result document, on request
  (:class:`ResultFile`): nothing but the document is written on the worker's critical path.

A new kind is one :func:`register` call beside the module that implements it, plus its routes (thin
calls into :mod:`api.routes.jobroutes`).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

#: The kind of rows written before kinds existed (``kind`` NULL).
DEFAULT_KIND = "plan"


@dataclass(frozen=True)
class ResultFile:
    """A download made from a succeeded job's result document.

    Attributes:
        name: The file name in the URL (``/api/v1/<collection>/{id}/<name>``), e.g. ``profile.csv``.
        link: The key of the job document's ``links`` pointing at it, e.g. ``profile_csv``.
        media_type: Its ``Content-Type``.
        maker: ``"module:function"``, ``function(source) -> bytes`` where ``source`` is a
            :class:`FileSource` (imported on first use, in the server).
        stored: Whether the made file is kept (written once, on the first request): files that are
            expensive to make (a plot: exact distances and matplotlib); cheap ones are made each time.
    """

    name: str
    link: str
    media_type: str
    maker: str
    stored: bool = False

    def make(self, source: FileSource) -> bytes:
        """Make the file from ``source``."""
        return bytes(_resolve(self.maker)(source))


@dataclass(frozen=True)
class FileSource:
    """What a file maker gets: the job's submitted input, its result document, and its mesh files.

    Attributes:
        job_id: The job.
        input: The input as stored (a scenario dict for plans).
        document: The result document (parsed JSON).
        meshes: ``{mesh id: local file path}`` of the tenant's meshes the input names.
        empty_dir: An empty folder (relative file names in the input resolve to nothing).
    """

    job_id: str
    input: dict[str, Any]
    document: dict[str, Any]
    meshes: dict[str, str]
    empty_dir: str


@dataclass(frozen=True)
class JobKind:
    """One kind of job (see the module docstring)."""

    name: str
    collection: str
    noun: str
    runner: str
    input_key: str = "scenario"
    files: tuple[ResultFile, ...] = field(default_factory=tuple)

    def file(self, name: str) -> ResultFile | None:
        """The download called ``name``, or ``None``."""
        return next((f for f in self.files if f.name == name), None)

    def run(self) -> Callable[..., dict[str, Any]]:
        """The worker-side function of this kind (imports its module)."""
        fn: Callable[..., dict[str, Any]] = _resolve(self.runner)
        return fn


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


def _resolve(dotted: str) -> Any:
    module, _, name = dotted.partition(":")
    return getattr(importlib.import_module(module), name)


#: Planning jobs: a scenario in, a drive profile (or a refusal) out; the CSV and the plot on request.
PLAN = register(
    JobKind(
        name="plan",
        collection="plans",
        noun="plan",
        runner="api.worker:plan_job",
        files=(
            ResultFile("profile.csv", "profile_csv", "text/csv; charset=utf-8", "api.worker:profile_csv"),
            ResultFile("plot.png", "plot_png", "image/png", "api.worker:plot_png", stored=True),
        ),
    )
)


#: Assembly cycles: a cycle document in, one cycle profile document (legs, events) or a refusal out.
CYCLE = register(
    JobKind(
        name="cycle",
        collection="cycles",
        noun="cycle",
        runner="api.cycles:cycle_job",
        input_key="cycle",
        files=(
            ResultFile(
                "profile.csv", "profile_csv", "text/csv; charset=utf-8", "api.cycles:cycle_profile_csv"
            ),
            ResultFile("plot.png", "plot_png", "image/png", "api.cycles:cycle_plot_png", stored=True),
        ),
    )
)

#: Campaigns: units installed one cycle each in a cabin that fills up; the summary and the cycle documents.
CAMPAIGN = register(
    JobKind(
        name="campaign",
        collection="campaigns",
        noun="campaign",
        runner="api.cycles:campaign_job",
        input_key="campaign",
        files=(
            ResultFile(
                "profile.csv", "profile_csv", "text/csv; charset=utf-8", "api.cycles:campaign_profile_csv"
            ),
            ResultFile("units.csv", "units_csv", "text/csv; charset=utf-8", "api.cycles:campaign_units_csv"),
            ResultFile("plot.png", "plot_png", "image/png", "api.cycles:campaign_plot_png", stored=True),
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
