"""The HTTP side every job kind shares: submit, the job document, get, list, files, cancel and delete.

A kind's routes (:mod:`api.routes.plans` for plans) parse and check their own input, then call these
helpers with their :class:`~api.jobkinds.JobKind`; the helpers call :class:`~api.jobstore.JobStore` and
turn its outcomes into answers:

* :func:`submit_request` answers a submit route's :class:`Submission` (the parsed body, JSON or YAML, and
  its ``Idempotency-Key``): it replays the key's job (200, ``Idempotent-Replayed: true``; 422
  ``idempotency_key_reused`` for another body), or has the kind's route check the body and make the job,
  which :func:`submit` queues under the tenant's quota (429 ``quota_exceeded`` with ``Retry-After``),
  answering 202 with the job document and ``Location``;
* :func:`job_answer` is the job document with its result document spliced in (the texts of recent
  results kept: :mod:`api.results`); :func:`waited_answer` is the same after a long poll (``wait_s``:
  answered when the job ends, :mod:`api.waiters`);
* :func:`file_answer` is a download of a succeeded job (:class:`~api.jobkinds.ResultFile`), made from
  the stored result on request (409 while the job is active, 404 when it did not succeed);
* :func:`cancel_or_delete`: queued -> cancelled, running -> killed by its owner (200, or 202 while the
  kill is pending after 10 s), finished -> deleted with its files (204).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any

from fastapi import Depends, Header, Query, Request, Response
from starlette.concurrency import run_in_threadpool

from api import results
from api.bodies import parse_body
from api.compact import unpack_json
from api.context import AppContext
from api.db import ACTIVE_STATES, TERMINAL_STATES, Job
from api.jobkinds import FileSource, JobKind, ResultFile
from api.jobstore import IdempotencyKeyReused, QuotaExceeded
from api.problems import Problem
from api.routes.inputs import empty_dir
from planner.core.exceptions import InvalidInput, InvalidMesh

#: A submit route's answer besides its 202: the replay of an earlier request with the same key.
REPLAY_RESPONSE: dict[int | str, dict[str, Any]] = {
    200: {"description": "Idempotent replay: the job of an earlier request with this key"}
}


@dataclass(frozen=True)
class Submission:
    """A submit request: its parsed body, its ``Idempotency-Key`` (if any), the response it is answered in."""

    body: Any
    key: str | None
    response: Response


async def _submission(
    request: Request,
    response: Response,
    idempotency_key: Annotated[
        str | None,
        Header(alias="Idempotency-Key", max_length=200, description="Same key + same body = same job."),
    ] = None,
) -> Submission:
    """The body parsed as JSON or YAML (400 / 415 otherwise: :func:`api.bodies.parse_body`) and the key."""
    body = parse_body(await request.body(), request.headers.get("content-type"))
    return Submission(body, idempotency_key, response)


#: The submission of a submit route (a dependency).
SubmissionDep = Annotated[Submission, Depends(_submission)]
#: Checks a kind's request body and makes its job: ``(ctx, tenant, body, key, request_sha256) -> Job``
#: (a :class:`~api.problems.Problem` for a bad body).
JobMaker = Callable[[AppContext, str, Any, str | None, str], Job]


def canonical_sha256(data: Any) -> str:
    """SHA-256 of a request body's canonical JSON (sorted keys): what an idempotent replay compares."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def job_url(kind: JobKind, job_id: str) -> str:
    """The job's URL path."""
    return f"/api/v1/{kind.collection}/{job_id}"


def job_document(kind: JobKind, row: Job, warming: str | None = None) -> dict[str, Any]:
    """The public job document (without the result: :func:`job_answer` adds it).

    Args:
        kind: The job's kind.
        row: The job.
        warming: The runner's warm-up stage, shown as the stage of a queued job while it lasts.
    """
    base = job_url(kind, row.id)
    stage = warming if row.status == "queued" and warming is not None else row.stage
    doc: dict[str, Any] = {
        "id": row.id,
        "status": row.status,
        "stage": stage,
        "progress": row.progress,
        kind.input_key: {"name": row.scenario_name, "sha256": row.provenance.get(f"{kind.input_key}_sha256")},
        "time_limit_s": row.time_limit_s,
        "attempts": row.attempts,
        "created_at": row.created_at,
        "started_at": row.started_at,
        "finished_at": row.finished_at,
        "reason": row.reason,
        "message": row.message,
        "provenance": row.provenance,
        "links": {"self": base},
    }
    for key, value in (row.progress_detail or {}).items():  # a campaign's units, as they stand
        doc.setdefault(key, value)
    if row.status == "succeeded":
        doc["links"].update({f.link: f"{base}/{f.name}" for f in kind.files})
    return doc


def tenant_job(ctx: AppContext, kind: JobKind, tenant: str, job_id: str) -> Job:
    """The tenant's job of ``kind``; 404 ``not_found`` otherwise."""
    row = ctx.jobs.get(tenant, job_id, kind)
    if row is None:
        raise Problem(404, "not_found", f"no {kind.noun} {job_id!r}")
    return row


def _id_field(kind: JobKind, job_id: str) -> dict[str, Any]:
    """``{"<noun>_id": job_id}``: the extra member of a problem naming a job (``plan_id``)."""
    return {f"{kind.noun}_id": job_id}


def _key_reused(kind: JobKind, exc: IdempotencyKeyReused) -> Problem:
    return Problem(
        422,
        "idempotency_key_reused",
        str(exc),
        errors=[{"field": "Idempotency-Key", "reason": "reused with a different body"}],
        **_id_field(kind, exc.job_id),
    )


def replay(
    ctx: AppContext, kind: JobKind, response: Response, tenant: str, key: str | None, request_sha256: str
) -> dict[str, Any] | None:
    """The answer replaying the tenant's job of ``Idempotency-Key`` ``key``, or ``None`` (none such).

    Called before the input is checked (a replay answers what the first request got, cheaply).
    """
    if key is None:
        return None
    try:
        row = ctx.jobs.replay(tenant, key, request_sha256)
    except IdempotencyKeyReused as exc:
        raise _key_reused(kind, exc) from None
    if row is None:
        return None
    response.status_code = 200
    response.headers["Location"] = job_url(kind, row.id)
    response.headers["Idempotent-Replayed"] = "true"
    return job_document(kind, row)


def submit_request(
    ctx: AppContext, kind: JobKind, tenant: str, submission: Submission, make: JobMaker
) -> dict[str, Any]:
    """The answer of a submit route: the replay of the key's job, else ``make``'s job queued (:func:`submit`).

    The replay is looked up before the body is checked (it answers what the first request got, cheaply).
    """
    request_sha256 = canonical_sha256(submission.body)
    replayed = replay(ctx, kind, submission.response, tenant, submission.key, request_sha256)
    if replayed is not None:
        return replayed
    job = make(ctx, tenant, submission.body, submission.key, request_sha256)
    return submit(ctx, kind, submission.response, job)


def submit(ctx: AppContext, kind: JobKind, response: Response, job: Job) -> dict[str, Any]:
    """Queue ``job`` (see the module docstring); the job document of the answer."""
    try:
        submitted = ctx.jobs.submit(job, ctx.settings.tenant_max_active_jobs)
    except QuotaExceeded as exc:
        raise Problem(
            429,
            "quota_exceeded",
            str(exc),
            headers={"Retry-After": str(ctx.settings.retry_after_s)},
            active_jobs=exc.active,
            limit=exc.limit,
        ) from None
    except IdempotencyKeyReused as exc:
        raise _key_reused(kind, exc) from None
    row = submitted.job
    response.headers["Location"] = job_url(kind, row.id)
    if submitted.replayed:
        response.status_code = 200
        response.headers["Idempotent-Replayed"] = "true"
    else:
        ctx.runner.wake()
    return job_document(kind, row)


def page(
    ctx: AppContext, kind: JobKind, tenant: str, status: str | None, limit: int, offset: int
) -> dict[str, Any]:
    """``{"items": [job, ...], "total", "limit", "offset"}`` of the tenant's jobs of ``kind``."""
    limit = min(limit, ctx.settings.page_size_max)
    rows, total = ctx.jobs.page(tenant, kind, status, limit, offset)
    warming = ctx.runner.warming()
    return {
        "items": [job_document(kind, r, warming) for r in rows],
        "total": total,
        "limit": limit,
        "offset": offset,
    }


def result_json(ctx: AppContext, row: Job) -> bytes | None:
    """The result document's JSON (kept, unpacked from storage, or a legacy text row), or ``None``."""
    if row.status in ACTIVE_STATES:
        return None
    kept = results.recall(row.id)
    if kept is not None:
        return kept
    packed, legacy = ctx.jobs.result_blob(row.id)
    found = unpack_json(packed) if packed is not None else legacy.encode() if legacy is not None else None
    if found is not None:
        results.remember(row.id, found)
    return found


def result_text(ctx: AppContext, row: Job) -> str | None:
    """:func:`result_json` as text."""
    found = result_json(ctx, row)
    return None if found is None else found.decode()


def forget_result(job_id: str) -> None:
    """Drop a deleted job's decoded result."""
    results.forget(job_id)


def job_answer(ctx: AppContext, kind: JobKind, tenant: str, job_id: str) -> Response:
    """The job document; once finished, ``result`` is its result document (refusal included)."""
    return _answer(ctx, kind, tenant_job(ctx, kind, tenant, job_id))


def _answer(ctx: AppContext, kind: JobKind, row: Job) -> Response:
    head = json.dumps(job_document(kind, row, ctx.runner.warming()), allow_nan=False, separators=(",", ":"))
    body = b"".join((head[:-1].encode(), b',"result":', result_json(ctx, row) or b"null", b"}"))
    return Response(body, media_type="application/json")


#: Largest ``wait_s`` a job document request may ask for [s] (the service caps it further:
#: ``Settings.job_wait_max_s``).
MAX_WAIT_S = 60.0

WaitQuery = Annotated[
    float,
    Query(
        ge=0.0,
        le=MAX_WAIT_S,
        description="Long poll: wait up to this many seconds for the job to end before answering (the "
        "answer comes as soon as it ends; at most the service's job_wait_max_s, 30 s by default). 0: "
        "answer at once.",
    ),
]


async def waited_answer(ctx: AppContext, kind: JobKind, tenant: str, job_id: str, wait_s: float) -> Response:
    """:func:`job_answer`, after waiting up to ``wait_s`` (capped) for an active job to end (long poll).

    An unknown job is a 404 at once; a job that ends while the request waits is answered then
    (:class:`api.waiters.JobWaiters`); one still active after the wait is answered as it is.
    """
    limit = min(wait_s, ctx.settings.job_wait_max_s)
    if limit <= 0.0:
        return await run_in_threadpool(job_answer, ctx, kind, tenant, job_id)

    async def read() -> Job:
        return await run_in_threadpool(tenant_job, ctx, kind, tenant, job_id)

    row = await ctx.waiters.until(job_id, limit, read, lambda r: r.status not in ACTIVE_STATES)
    return await run_in_threadpool(_answer, ctx, kind, row)


def succeeded(ctx: AppContext, kind: JobKind, tenant: str, job_id: str, what: str) -> Job:
    """The tenant's succeeded job; 409 ``not_finished`` while active, 404 when it did not succeed."""
    row = tenant_job(ctx, kind, tenant, job_id)
    if row.status in ACTIVE_STATES:
        raise Problem(
            409, "not_finished", f"{kind.noun} {job_id} is {row.status}; the {what} exists once it succeeds"
        )
    if row.status != "succeeded":
        raise Problem(404, "not_found", f"{kind.noun} {job_id} {row.status}: it has no {what}")
    return row


def file_answer(ctx: AppContext, kind: JobKind, tenant: str, job_id: str, name: str, what: str) -> Response:
    """The download ``name`` of a succeeded job, made from its stored result (kept when ``stored``)."""
    spec = kind.file(name)
    assert spec is not None, f"{kind.name} has no file {name}"
    row = succeeded(ctx, kind, tenant, job_id, what)
    data = ctx.jobs.stored_file(row.id, name)
    if data is None:
        data = _make(ctx, kind, row, spec, what)
        if spec.stored:
            ctx.jobs.store_file(row.id, name, data)
    return Response(data, media_type=spec.media_type)


def _make(ctx: AppContext, kind: JobKind, row: Job, spec: ResultFile, what: str) -> bytes:
    text = result_text(ctx, row)
    if text is None:
        raise Problem(404, "not_found", f"{kind.noun} {row.id}: it has no {what}")
    empty = empty_dir(ctx)
    try:
        meshes = ctx.store.local_files(dict(row.meshes))  # the files may have come through another instance
        source = FileSource(row.id, dict(row.scenario), json.loads(text), meshes, str(empty))
        return spec.make(source)
    except (InvalidMesh, InvalidInput, OSError, ValueError) as exc:
        raise Problem(
            404,
            "not_found",
            f"{kind.noun} {row.id}: its {what} cannot be made ({exc}); was its cabin deleted?",
        ) from None


def cancel_or_delete(ctx: AppContext, kind: JobKind, tenant: str, job_id: str) -> Response:
    """Queued -> cancelled; running -> killed by its owner; finished -> deleted (see the module docstring)."""
    row = tenant_job(ctx, kind, tenant, job_id)
    if row.status in TERMINAL_STATES:
        ctx.jobs.delete_finished([job_id])
        forget_result(job_id)
        return Response(status_code=204)
    outcome = ctx.jobs.cancel([job_id], "cancelled by the client")
    ctx.waiters.notify(job_id)  # a queued job is cancelled now (a running one when its owner kills it)
    if outcome.running:
        ctx.runner.cancel(job_id)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            if tenant_job(ctx, kind, tenant, job_id).status in TERMINAL_STATES:
                break
            time.sleep(0.05)
    row = tenant_job(ctx, kind, tenant, job_id)
    status = 200
    if row.status in ACTIVE_STATES:  # the kill is still pending (e.g. the process is being started)
        status = 202
    elif row.status != "cancelled":
        raise Problem(
            409, "already_finished", f"{kind.noun} {job_id} {row.status} before it could be cancelled"
        )
    body = json.dumps(job_document(kind, row), allow_nan=False, separators=(",", ":"))
    return Response(body, status_code=status, media_type="application/json")


__all__ = [
    "REPLAY_RESPONSE",
    "JobMaker",
    "Submission",
    "SubmissionDep",
    "cancel_or_delete",
    "canonical_sha256",
    "file_answer",
    "forget_result",
    "job_answer",
    "job_document",
    "job_url",
    "page",
    "replay",
    "result_json",
    "result_text",
    "submit",
    "submit_request",
    "succeeded",
    "tenant_job",
    "waited_answer",
]
