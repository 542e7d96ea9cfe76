"""The decoded result texts of recently finished jobs, kept in memory (one cache per service process).

A finished job's result document is stored packed (:mod:`api.compact`); its JSON text is what a client
reads (``GET /plans/{id}`` and the other kinds' job documents, the exports, the scene). The texts of
the last :data:`RESULTS_KEPT` jobs (at most :data:`RESULTS_MAX_CHARS` characters) are kept here: put by
the job runner as a job ends (the worker sends the text with the packed blob,
:func:`api.compact.document_text`, so even the first read unpacks nothing) and by the first read of an
older job (which unpacks the stored blob). Results never change once written; a deleted job's text is
dropped (:func:`forget`).
"""

from __future__ import annotations

from planner.core.lru import BoundedLRU

#: Texts kept at most: enough for every job that ends between two reads on a busy service.
RESULTS_KEPT = 32
#: Characters kept at most, all texts together (a plan's text is 2-5 MB); the latest text is always kept.
RESULTS_MAX_CHARS = 96_000_000

_RESULTS: BoundedLRU[str, str] = BoundedLRU(RESULTS_KEPT, len, RESULTS_MAX_CHARS)


def recall(job_id: str) -> str | None:
    """The kept text of job ``job_id``, or ``None``."""
    return _RESULTS.get(job_id)


def remember(job_id: str, text: str) -> None:
    """Keep ``text`` as job ``job_id``'s result text; the oldest texts beyond the bounds go."""
    _RESULTS.put(job_id, text)


def forget(job_id: str) -> None:
    """Drop job ``job_id``'s text (the job was deleted)."""
    _RESULTS.pop(job_id)


__all__ = ["RESULTS_KEPT", "RESULTS_MAX_CHARS", "forget", "recall", "remember"]
