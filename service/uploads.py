"""Receiving a mesh upload: stream to a temp file (size-capped, hashed), inspect it safely in a
child process, file it content-addressed, and record who uploaded it."""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import AsyncIterator
from pathlib import Path

from sqlalchemy.exc import IntegrityError
from starlette.concurrency import run_in_threadpool

from jobqueue.db import MeshOwner, MeshRecord, utcnow
from models.mesh.sandbox import wording
from service.context import Context
from service.jobs import check_quota
from service.mesh_check import UploadRejected, extension_of, inspect_upload
from service.schemas import MeshOut
from service.wording import said_bytes

CHUNK = 1 << 20
_UGRID_KIND = re.compile(r"\.(b8l|b8|b4|lb8l|lb8|lb4|r8|r4|lr8|lr4)\.ugrid$")


RAW_HINT = "send the mesh file as the request body"
MULTIPART_HINT = "send the mesh file in multipart field 'file'"
FORM_HINT = "send the mesh file base64-encoded in field file_b64"


def mesh_key(ext: str):
    """The hash that names an upload: its bytes and its format extension, which picks the reader
    (the same bytes as .vtu and as .stl are two meshes, or one of them is no mesh at all)."""
    return hashlib.sha256(f"magnet-mesh:{ext}\n".encode())


async def receive_mesh(
    ctx: Context, user: str, chunks: AsyncIterator[bytes], filename: str | None, hint: str = RAW_HINT
) -> MeshOut:
    """Store one uploaded mesh for `user`; the same bytes under the same format always give the same
    id. `hint`: how this way in takes the file (said when it came empty)."""
    ext = extension_of(filename)
    base = os.path.basename((filename or "").replace("\\", "/"))
    kind = _UGRID_KIND.search(base.lower()) if ext == "ugrid" else None
    if kind:  # (meshio tells a UGRID file's byte order and widths by the suffix before .ugrid)
        ext = f"{kind.group(1)}.ugrid"
    stem = base[: -len(ext) - 1] if base.lower().endswith("." + ext) else Path(base).stem
    limit = ctx.settings.max_upload_bytes
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", stem)[:100] or "mesh"
    tmp = ctx.storage.temp_file(f"{safe}.{ext}")
    digest, size = mesh_key(ext), 0
    try:
        with open(tmp, "wb") as out:
            async for chunk in chunks:
                size += len(chunk)
                if size > limit:
                    raise UploadRejected(413, f"mesh file too large: the limit is {said_bytes(limit)}")
                digest.update(chunk)
                out.write(chunk)
        if size == 0:  # (the CLI's words for an empty file, and how this way in takes one)
            name = os.path.basename((filename or "").replace("\\", "/"))[:100] or "the upload"
            raise UploadRejected(422, f"{wording('the file is empty (0 bytes)', name)}; {hint}")
        mesh_id = digest.hexdigest()
        return await run_in_threadpool(_file_mesh, ctx, user, tmp, mesh_id, ext, size, filename)
    finally:
        ctx.storage.discard_temp(tmp)


def _file_mesh(
    ctx: Context, user: str, tmp, mesh_id: str, ext: str, size: int, filename: str | None
) -> MeshOut:
    with ctx.db.session() as s:
        owned = s.get(MeshOwner, (mesh_id, user)) is not None
    if not owned:
        check_quota(ctx.db, ctx.storage, ctx.settings, user, size, 413)
    with ctx.db.session() as s:
        mesh = s.get(MeshRecord, mesh_id)
    if mesh is None:
        s_ = ctx.settings
        info = inspect_upload(tmp, ext, s_.max_cells, s_.parse_memory_bytes, s_.parse_timeout_s)
        ctx.storage.put_mesh(tmp, mesh_id, ext)
        mesh = MeshRecord(id=mesh_id, ext=ext, size=size, info=info, created_at=utcnow())
        with ctx.db.session() as s:
            try:
                s.add(mesh)
                s.commit()
            except IntegrityError:  # the same bytes uploaded concurrently
                s.rollback()
                mesh = s.get(MeshRecord, mesh_id)
    name = (filename or f"mesh.{ext}").replace("\\", "/").rsplit("/", 1)[-1][:300]
    with ctx.db.session() as s:
        owner = s.get(MeshOwner, (mesh_id, user))
        if owner is not None and owner.filename != name:  # (the name this upload gave it)
            owner.filename = name
            s.commit()
        if owner is None:
            owner = MeshOwner(mesh_id=mesh_id, user=user, filename=name, created_at=utcnow())
            try:
                s.add(owner)
                s.commit()
            except IntegrityError:
                s.rollback()
                owner = s.get(MeshOwner, (mesh_id, user))
    return mesh_out(mesh, owner)


def mesh_out(mesh: MeshRecord, owner: MeshOwner) -> MeshOut:
    info = mesh.info
    return MeshOut(
        id=mesh.id,
        filename=owner.filename,
        size=mesh.size,
        cells=info["cells"],
        points=info["points"],
        dim=info["dim"],
        cell_types=info.get("cell_types", {}),
        lower_dim_cells=info.get("lower_dim_cells", {}),
        physical_groups=info.get("physical_groups", []),
        boundary_groups=info.get("boundary_groups", []),
        boundary=info.get("boundary"),
        bbox=info.get("bbox", []),
        surface=info.get("surface"),
        check=info.get("check"),
        created_at=owner.created_at,
    )


async def stream_of(upload) -> AsyncIterator[bytes]:
    """Chunks of a starlette UploadFile."""
    while chunk := await upload.read(CHUNK):
        yield chunk
