"""The cabin mesh store: uploaded bytes on disk by content hash, metadata per tenant in the database.

A mesh's id is the SHA-256 of its bytes. The bytes are stored once in the database
(:class:`~api.db.MeshBlob`), so every instance sharing it can plan with them, and written (atomically,
fsynced) as ``<data_dir>/meshes/<sha256>.<ext>``, this instance's file of them (another instance writes
its own on first use, :func:`local_mesh_file`). Tenants who upload the same bytes share them; each tenant
has its own metadata row, so one tenant never sees another's meshes. Uploads are parsed and validated
with :func:`planner.meshio.load_mesh` before anything is stored.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
import threading
from pathlib import Path
from typing import Any, Literal

from sqlalchemy import delete, func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from api.db import Database, Mesh, MeshBlob, now_s
from api.jobstore import JobStore
from api.problems import Problem
from planner.core.exceptions import InvalidInput, InvalidMesh
from planner.meshes import reference_cabin_path
from planner.meshio import SUPPORTED_EXTENSIONS, MeshLimits, load_mesh
from planner.scenario.resolve import MeshResolver

_LOG = logging.getLogger(__name__)


def scenario_mesh_resolver(meshes: dict[str, str]) -> MeshResolver:
    """A scenario mesh resolver mapping a tenant's mesh ids to their files, refusing any other file.

    Reference cabin names pass through (``None``: `resolve_scenario` finds them);
    any other name raises, so a scenario sent over HTTP never reads a file of the server.

    Args:
        meshes: Mesh id -> stored file path.
    """

    def resolve(name: str) -> Path | bytes | None:
        if name in meshes:
            return Path(meshes[name])
        if reference_cabin_path(name) is not None:
            return None
        raise InvalidInput(f"mesh {name!r}: not an uploaded mesh id of this tenant", field="cabin.mesh")

    return resolve


def local_mesh_file(db: Database, root: Path, stored: str) -> Path:
    """This instance's file of a stored mesh, fetched from the database when another instance stored it.

    ``stored`` is the path a job or sweep recorded (``<sha256><ext>`` in the data directory of the
    instance that took the upload). Instances sharing one database keep their own data directories: the
    file is looked up under this instance's ``root`` by its name and, when missing, written there from
    :class:`~api.db.MeshBlob` (atomically, after checking its SHA-256).

    Raises:
        FileNotFoundError: neither the file nor its bytes are stored (the mesh was deleted).
    """
    name = Path(stored).name
    local = root / name
    if local.is_file():
        return local
    sha256 = name.split(".", 1)[0]
    with db.session() as s:
        blob = s.get(MeshBlob, sha256)
        data = blob.data if blob is not None else None
    if data is None:
        raise FileNotFoundError(f"mesh {sha256}: neither on this instance nor in the database")
    if hashlib.sha256(data).hexdigest() != sha256:
        raise FileNotFoundError(f"mesh {sha256}: the stored bytes do not match their hash")
    root.mkdir(parents=True, exist_ok=True)
    MeshStore.write_file(local, data)
    return local


#: Serialises this instance's mesh uploads and deletes (the row lock of :func:`_lock_blob` does it across
#: instances on PostgreSQL; SQLite serves one instance).
_BLOB_LOCK = threading.Lock()
_MESH_COLUMNS = (
    "tenant",
    "sha256",
    "name",
    "filename",
    "units",
    "byte_size",
    "n_faces",
    "n_vertices",
    "report",
    "created_at",
)


def _lock_blob(s: Session, sha256: str) -> str | None:
    """The stored bytes' key, its row locked until the transaction ends (``FOR UPDATE``), or None."""
    return s.scalar(select(MeshBlob.sha256).where(MeshBlob.sha256 == sha256).with_for_update())


def _file_names(meshes: dict[str, str] | None) -> set[str]:
    return {Path(v).name for v in (meshes or {}).values()}


def mesh_document(row: Mesh) -> dict[str, Any]:
    """The public description of a stored mesh."""
    return {
        "id": row.sha256,
        "name": row.name,
        "filename": row.filename,
        "units": row.units,
        "byte_size": row.byte_size,
        "n_faces": row.n_faces,
        "n_vertices": row.n_vertices,
        "bounds_min_m": row.report.get("bounds_min_m"),
        "bounds_max_m": row.report.get("bounds_max_m"),
        "format": row.report.get("format"),
        "file_units": row.report.get("file_units"),
        "surface_deviation_m": row.report.get("surface_deviation_m", 0.0),
        "is_closed": row.report.get("is_closed"),
        "reference": False,
        "created_at": row.created_at,
    }


class MeshInUse(Exception):
    """A mesh cannot be deleted while active jobs plan in it."""

    def __init__(self, mesh_id: str, job_ids: list[str]) -> None:
        super().__init__(f"cabin {mesh_id!r} is used by active plan(s) {', '.join(job_ids)}")
        self.mesh_id = mesh_id
        self.job_ids = job_ids


class MeshStore:
    """Uploaded meshes of every tenant.

    Args:
        db: The database holding the metadata rows.
        root: Folder of the mesh files (created).
        limits: Caps applied when an upload is parsed.
    """

    def __init__(self, db: Database, root: Path, limits: MeshLimits) -> None:
        self.db = db
        self.root = root
        self.limits = limits
        root.mkdir(parents=True, exist_ok=True)

    def path_of(self, row: Mesh) -> Path:
        """File of a stored mesh (on this instance's disk or not yet: :meth:`local_path`)."""
        return self.root / f"{row.sha256}{Path(row.filename).suffix.lower()}"

    def local_path(self, row: Mesh) -> Path:
        """This instance's file of a stored mesh, fetched from the database if another instance took it."""
        return local_mesh_file(self.db, self.root, str(self.path_of(row)))

    def local_files(self, meshes: dict[str, str]) -> dict[str, str]:
        """A job's ``{mesh id: stored path}`` as this instance's files (:func:`local_mesh_file`)."""
        return {k: str(local_mesh_file(self.db, self.root, v)) for k, v in meshes.items()}

    def add(
        self, tenant: str, data: bytes, filename: str, units: Literal["m", "mm"], name: str
    ) -> tuple[Mesh, bool]:
        """Validate and store an upload; returns (metadata row, created) (``False`` when already stored).

        Raises:
            Problem: 422 with the loader's reason (``details.check``) when the mesh cannot be used; 409 when
                the same bytes are already stored for this tenant with other units.
        """
        ext = Path(filename).suffix.lower().lstrip(".")
        if ext not in SUPPORTED_EXTENSIONS:
            raise Problem(
                422,
                "invalid_mesh",
                f"file: extension {('.' + ext) if ext else '(none)'!r} is not one of "
                f"{', '.join('.' + e for e in SUPPORTED_EXTENSIONS)}",
                errors=[{"field": "file", "reason": "unsupported extension"}],
                reason="invalid_mesh",
                details={"check": "name", "file": filename},
            )
        try:
            mesh = load_mesh(data, units=units, name=filename, limits=self.limits)
        except InvalidMesh as exc:
            raise Problem(
                422,
                "invalid_mesh",
                exc.message,
                errors=[{"field": "file", "reason": exc.message}],
                reason=exc.reason,
                details={k: _plain(v) for k, v in exc.details.items()},
            ) from None
        with self.db.session() as s:
            found = s.scalar(select(Mesh).where(Mesh.tenant == tenant, Mesh.sha256 == mesh.sha256))
            if found is not None:
                if found.units != units:
                    raise Problem(
                        409,
                        "mesh_units_conflict",
                        f"this mesh is already stored (id {found.sha256}) with units {found.units!r}",
                        id=found.sha256,
                    )
                return found, False
        row = Mesh(
            tenant=tenant,
            sha256=mesh.sha256,
            name=name,
            filename=Path(filename).name[:255],
            units=units,
            byte_size=len(data),
            n_faces=mesh.report.n_faces,
            n_vertices=mesh.report.n_vertices,
            report={k: _plain(v) for k, v in mesh.report.to_dict().items()},
            created_at=now_s(),
        )
        self.write_file(self.path_of(row), data)
        # The metadata row and the bytes (once per content hash, for every instance sharing the database)
        # in one transaction holding the bytes' row: a concurrent delete of the last other reference
        # either ran before (and the bytes are stored again here) or waits and then counts this row.
        for attempt in range(2):
            try:
                with _BLOB_LOCK, self.db.session() as s:
                    if _lock_blob(s, mesh.sha256) is None:
                        s.add(MeshBlob(sha256=mesh.sha256, data=data, created_at=now_s()))
                    s.add(row)
                break
            except IntegrityError:  # another instance stored the same bytes first: they are there now
                if attempt:
                    raise
                row = Mesh(**{c: getattr(row, c) for c in _MESH_COLUMNS})
        return row, True

    def get(self, tenant: str, mesh_id: str) -> Mesh | None:
        """The tenant's mesh of that id, or ``None``."""
        with self.db.session() as s:
            return s.scalar(select(Mesh).where(Mesh.tenant == tenant, Mesh.sha256 == mesh_id))

    def list(self, tenant: str, limit: int, offset: int) -> tuple[list[Mesh], int]:
        """A page of the tenant's meshes (newest first) and their total count."""
        with self.db.session() as s:
            rows = s.scalars(
                select(Mesh)
                .where(Mesh.tenant == tenant)
                .order_by(Mesh.created_at.desc(), Mesh.pk.desc())
                .limit(limit)
                .offset(offset)
            ).all()
            total = s.scalar(select(func.count()).select_from(Mesh).where(Mesh.tenant == tenant)) or 0
        return list(rows), int(total)

    def delete(self, tenant: str, mesh_id: str) -> bool:
        """Forget the tenant's mesh; the file goes when no tenant refers to it. ``False`` if unknown.

        Raises:
            MeshInUse: a queued or running job of the tenant plans in this cabin (deleting it would fail
                the job): cancel the job or wait for it.
        """
        with _BLOB_LOCK, self.db.session() as s:
            _lock_blob(s, mesh_id)  # an upload of the same bytes waits (see add)
            row = s.scalar(select(Mesh).where(Mesh.tenant == tenant, Mesh.sha256 == mesh_id))
            if row is None:
                return False
            path = self.path_of(row)
            active = JobStore.active_jobs(s, tenant)
            # Jobs name the file by the path of the instance that took the upload: compare the names.
            users = sorted(j.id for j in active if path.name in _file_names(j.meshes))
            if users:
                raise MeshInUse(mesh_id, users)
            s.delete(row)
            s.flush()
            others = s.scalar(select(func.count()).select_from(Mesh).where(Mesh.sha256 == mesh_id)) or 0
            if not others:
                s.execute(delete(MeshBlob).where(MeshBlob.sha256 == mesh_id))
        if not others:
            try:
                path.unlink()
            except FileNotFoundError:
                pass
        return True

    @staticmethod
    def write_file(path: Path, data: bytes) -> None:
        """Write ``data`` to ``path`` atomically (temp file, fsync, rename), unless it already exists."""
        if path.is_file() and path.stat().st_size == len(data):
            return
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".upload-")
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise


def _plain(value: Any) -> Any:
    """JSON-friendly copy of report values (tuples become lists)."""
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, str | int | float | bool) or value is None:
        return value
    return str(value)


__all__ = ["MeshStore", "local_mesh_file", "mesh_document", "scenario_mesh_resolver"]
