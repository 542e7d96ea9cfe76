"""The types of the job machinery: a job kind, its downloads, what a download is made from.

Kept apart from the registry (:mod:`api.jobkinds`), which names each kind's functions: the job store and
the job functions themselves import these types, and the registry imports the job functions.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final

#: Name prefix of the files a running job keeps for a relaunch (:meth:`api.jobstore.JobStore.keep`: a
#: campaign's finished cycles).
KEEP_PREFIX: Final = "keep/"

#: The kind of rows written before kinds existed (``kind`` NULL).
DEFAULT_KIND = "plan"


@dataclass(frozen=True)
class ResultFile:
    """A download made from a succeeded job's result document.

    Attributes:
        name: The file name in the URL (``/api/v1/<collection>/{id}/<name>``), e.g. ``profile.csv``.
        link: The key of the job document's ``links`` pointing at it, e.g. ``profile_csv``.
        media_type: Its ``Content-Type``.
        maker: ``maker(source) -> bytes`` where ``source`` is a :class:`FileSource` (run in the server's
            thread pool; a maker imports what it needs inside, so registering it costs nothing).
        stored: Whether the made file is kept (written once, on the first request): files that are
            expensive to make (a plot: exact distances and matplotlib); cheap ones are made each time.
    """

    name: str
    link: str
    media_type: str
    maker: Callable[[FileSource], bytes]
    stored: bool = False

    def make(self, source: FileSource) -> bytes:
        """Make the file from ``source``."""
        return bytes(self.maker(source))


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
    runner: Callable[[dict[str, Any], Any], dict[str, Any]]
    input_key: str = "scenario"
    files: tuple[ResultFile, ...] = field(default_factory=tuple)

    def file(self, name: str) -> ResultFile | None:
        """The download called ``name``, or ``None``."""
        return next((f for f in self.files if f.name == name), None)


__all__ = ["DEFAULT_KIND", "KEEP_PREFIX", "FileSource", "JobKind", "ResultFile"]
