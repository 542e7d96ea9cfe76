"""The JSON of recently finished jobs' results, kept in memory (one cache per service process).

A finished job's result document is stored packed (:mod:`api.compact`); its JSON text is what a client
reads (``GET /plans/{id}`` and the other kinds' job documents, the exports, the scene). The JSON (UTF-8
bytes, spliced into answers as they are) of the last :data:`RESULTS_KEPT` jobs (at most
:data:`RESULTS_MAX_BYTES` bytes) is kept here: put by the job runner as a job ends (the worker sends it
with the packed blob, :func:`api.compact.document_json`, so even the first read unpacks nothing) and by
the first read of an older job (which unpacks the stored blob). Results never change once written; a
deleted job's is dropped (:func:`forget`).
"""

from __future__ import annotations

from planner.core.lru import BoundedLRU

#: Results kept at most: enough for every job that ends between two reads on a busy service.
RESULTS_KEPT = 32
#: Bytes kept at most, all results together (a plan's JSON is 2-5 MB); the latest is always kept.
RESULTS_MAX_BYTES = 96_000_000

_RESULTS: BoundedLRU[str, bytes] = BoundedLRU(RESULTS_KEPT, len, RESULTS_MAX_BYTES)


def recall(job_id: str) -> bytes | None:
    """The kept result JSON of job ``job_id``, or ``None``."""
    return _RESULTS.get(job_id)


def remember(job_id: str, result: bytes) -> None:
    """Keep ``result`` as job ``job_id``'s result JSON; the oldest beyond the bounds go."""
    _RESULTS.put(job_id, result)


def forget(job_id: str) -> None:
    """Drop job ``job_id``'s result JSON (the job was deleted)."""
    _RESULTS.pop(job_id)


__all__ = ["RESULTS_KEPT", "RESULTS_MAX_BYTES", "forget", "recall", "remember"]
