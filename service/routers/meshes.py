"""Mesh uploads: raw body (?filename=...) or multipart field `file`; content-addressed ids."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Path, Query, Request, Response

from service.auth import current_user
from service.context import Context, get_context
from service.jobs import delete_mesh, visible_mesh
from service.mesh_check import ALLOWED_EXTENSIONS, UploadRejected
from service.openapi import errors
from service.schemas import MeshOut
from service.uploads import MULTIPART_HINT, mesh_out, receive_mesh, stream_of

router = APIRouter(prefix="/v1", tags=["meshes"])

UPLOAD_BODY = {
    "requestBody": {
        "required": True,
        "content": {
            "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["file"],
                    "properties": {"file": {"type": "string", "format": "binary"}},
                }
            },
        },
    }
}
ERRORS = errors(401, 404)  # reading one of your own meshes or jobs
MESH_ID = Path(description="The mesh id (sha256 of its bytes), as POST /v1/meshes answered it.")


async def multipart_file(request: Request):
    """The `file` part of a multipart request (422 when absent)."""
    form = await request.form(max_files=1, max_fields=100)
    upload = form.get("file")
    if upload is None or isinstance(upload, str):
        raise UploadRejected(422, "multipart upload needs a file in field 'file'")
    return form, upload


@router.post(
    "/meshes",
    status_code=201,
    response_model=MeshOut,
    responses=errors(401, 413, 422),
    openapi_extra=UPLOAD_BODY,
)
async def upload_mesh(
    request: Request,
    filename: str | None = Query(
        None,
        max_length=300,
        description=f"name with the format extension ({', '.join(ALLOWED_EXTENSIONS)}); "
        "required for a raw body",
    ),
    user: str = Depends(current_user),
    ctx: Context = Depends(get_context),
) -> MeshOut:
    """Store a mesh (the same bytes give the same id) and answer what it contains."""
    if request.headers.get("content-type", "").startswith("multipart/form-data"):
        _, upload = await multipart_file(request)
        return await receive_mesh(ctx, user, stream_of(upload), upload.filename or filename, MULTIPART_HINT)
    return await receive_mesh(ctx, user, request.stream(), filename)


@router.get("/meshes/{mesh_id}", response_model=MeshOut, responses=ERRORS)
def get_mesh(
    mesh_id: str = MESH_ID, user: str = Depends(current_user), ctx: Context = Depends(get_context)
) -> MeshOut:
    """A mesh you uploaded."""
    with ctx.db.session() as s:
        mesh, owner = visible_mesh(s, user, mesh_id)
    return mesh_out(mesh, owner)


@router.delete("/meshes/{mesh_id}", status_code=204, responses=errors(401, 404, 409))
def remove_mesh(
    mesh_id: str = MESH_ID, user: str = Depends(current_user), ctx: Context = Depends(get_context)
):
    """Delete your upload of a mesh (409 while one of your jobs on it is queued or running); your
    finished jobs and their results stay. The file goes once no other user holds the same bytes."""
    delete_mesh(ctx.db, ctx.storage, user, mesh_id)
    return Response(status_code=204)
