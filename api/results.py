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

import threading
from collections import OrderedDict

#: Texts kept at most: enough for every job that ends between two reads on a busy service.
RESULTS_KEPT = 32
#: Characters kept at most, all texts together (a plan's text is 2-5 MB); the latest text is always kept.
RESULTS_MAX_CHARS = 96_000_000

_RESULTS: OrderedDict[str, str] = OrderedDict()
_LOCK = threading.Lock()


def recall(job_id: str) -> str | None:
    """The kept text of job ``job_id``, or ``None``."""
    with _LOCK:
        text = _RESULTS.get(job_id)
        if text is not None:
            _RESULTS.move_to_end(job_id)
        return text


def remember(job_id: str, text: str) -> None:
    """Keep ``text`` as job ``job_id``'s result text; the oldest texts beyond the bounds go."""
    with _LOCK:
        _RESULTS[job_id] = text
        _RESULTS.move_to_end(job_id)
        while len(_RESULTS) > 1 and (
            len(_RESULTS) > RESULTS_KEPT or sum(map(len, _RESULTS.values())) > RESULTS_MAX_CHARS
        ):
            _RESULTS.popitem(last=False)


def forget(job_id: str) -> None:
    """Drop job ``job_id``'s text (the job was deleted)."""
    with _LOCK:
        _RESULTS.pop(job_id, None)


__all__ = ["RESULTS_KEPT", "RESULTS_MAX_CHARS", "forget", "recall", "remember"]
