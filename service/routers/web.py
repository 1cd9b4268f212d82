"""The web page at `/` (plain HTML/CSS/JS shipped in service/web, nothing fetched at run time) and
the JSON it needs beyond the API: the polygons of a finished 2D job, for drawing it as SVG, and for
a hierarchy job its levels (numbers, and each 2D level's polygons) and the fine mesh's cells."""

from __future__ import annotations

import html
import json
import math
import os
import tempfile
import uuid
import zipfile
from pathlib import Path

import numpy as np
from fastapi import APIRouter, Depends, FastAPI
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

from jobqueue.db import MeshRecord
from service.auth import current_user
from service.context import Context, get_context
from service.jobs import NotFound, visible_job, visible_mesh
from service.mesh_check import UploadRejected, level_picture, upload_polygons
from service.openapi import binary, errors
from service.routers.jobs import JOB_ID, result_file
from service.routers.meshes import MESH_ID
from service.schemas import ErrorOut

WEB_DIR = Path(__file__).resolve().parents[1] / "web"
router = APIRouter()
# the page loads only its own files and talks only to this server (pictures arrive as blob: URLs)
PAGE_POLICY = (
    "default-src 'self'; img-src 'self' blob: data:; object-src 'none'; base-uri 'none'; "
    "frame-ancestors 'none'; form-action 'none'"
)


def mount_page(app: FastAPI) -> None:
    """Serve the page at `/` and its script and style under `/static/`."""
    app.include_router(router)
    app.mount("/static", StaticFiles(directory=WEB_DIR), name="static")


@router.get("/", include_in_schema=False)
def index() -> HTMLResponse:
    """The web page (no auth: the page itself asks for the API key and sends it with every call),
    its list of accepted extensions the readers' (models.mesh.formats, as the upload check)."""
    from models.mesh.formats import ARCHIVE_ONLY, MAY_STAND_ALONE
    from service.mesh_check import ALLOWED_EXTENSIONS

    shown = " ".join("." + e for e in ALLOWED_EXTENSIONS)
    shown += f" ({' '.join(ARCHIVE_ONLY)} with its data files: in a .zip or .tar.gz;"
    shown += f" {' '.join(MAY_STAND_ALONE)} alone when its data are inline)"
    page = (WEB_DIR / "index.html").read_text()
    page = page.replace("{{EXTENSIONS}}", html.escape(shown))
    return HTMLResponse(
        page,
        headers={"Cache-Control": "no-cache", "Content-Security-Policy": PAGE_POLICY},
    )


def element_polygons(vtu: Path) -> dict:
    """Boundary loops of the elements of an agglomerated 2D mesh, in element order, as flat arrays:
    points [[x, y], ...] (only those used, rounded to ~7 significant digits of the extent),
    connectivity (indices into points) cut by offsets (element i is connectivity[offsets[i]:offsets[i+1]]),
    and every cell-data array of the file (element_id, measure, n_fine_cells, the metrics, ...)."""
    import meshio

    mesh = meshio.read(vtu)
    blocks = [b.data for b in mesh.cells]
    sizes = np.concatenate([np.full(len(b), b.shape[1]) for b in blocks])
    loops = np.concatenate([b.ravel() for b in blocks])
    data = {
        name: np.concatenate([np.asarray(a).ravel() for a in arrays])
        for name, arrays in mesh.cell_data.items()
    }
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    order = np.argsort(data["element_id"], kind="stable") if "element_id" in data else np.arange(len(sizes))
    sizes, starts = sizes[order], starts[order]
    # gather the loops in element order without a Python loop: index of every vertex slot
    slot = np.repeat(starts - np.r_[0, np.cumsum(sizes)[:-1]], sizes) + np.arange(sizes.sum())
    used, connectivity = np.unique(loops[slot], return_inverse=True)
    points = mesh.points[used, :2]
    extent = float(np.ptp(points, axis=0).max()) or 1.0
    decimals = max(0, 7 - math.ceil(math.log10(extent)))
    cell_data = {}
    for name, values in data.items():
        values = values[order]
        cell_data[name] = (
            values.tolist() if values.dtype.kind in "iub" else np.round(values.astype(float), 6).tolist()
        )
    return {
        "points": np.round(points, decimals).tolist(),
        "connectivity": connectivity.tolist(),
        "offsets": np.r_[0, np.cumsum(sizes)].tolist(),
        "cell_data": cell_data,
    }


POLYGON_ERRORS = {
    401: {"model": ErrorOut, "description": "missing or invalid API key"},
    404: {"model": ErrorOut, "description": "no such job (or another user's), or a 3D job"},
    409: {"model": ErrorOut, "description": "the job has not succeeded (yet)"},
}


@router.get("/v1/jobs/{job_id}/polygons", tags=["jobs"], responses=POLYGON_ERRORS)
def job_polygons(
    job_id: str = JOB_ID, user: str = Depends(current_user), ctx: Context = Depends(get_context)
) -> dict:
    """The elements of a finished 2D job as polygons (what the web page draws): `points`,
    `connectivity` cut by `offsets`, and per-element `cell_data` (metrics, measure, ...).
    404 for a 3D job."""
    metrics = json.loads(result_file(ctx, user, job_id, "metrics.json").read_text())
    if metrics.get("dim") != 2:
        raise NotFound("polygons are drawn for 2D meshes only; see preview.png for a 3D job")
    return element_polygons(result_file(ctx, user, job_id, "mesh.vtu"))


# --- hierarchies on the page: the levels' numbers, each level's polygons, the fine mesh ------------

DRAWN_CELLS = 200_000  # the fine mesh is drawn under the levels up to this many cells
LEVEL = PathParam(ge=0, le=10_000, description="Level number: 0 is the coarsest, the last the finest.")


def _hierarchy(ctx: Context, user: str, job_id: str) -> tuple[zipfile.ZipFile, dict]:
    zf = zipfile.ZipFile(result_file(ctx, user, job_id, "hierarchy.zip"))
    return zf, json.loads(zf.read("hierarchy.json"))


@router.get("/v1/jobs/{job_id}/hierarchy/levels", tags=["jobs"], responses=errors(401, 404, 409))
def hierarchy_levels(
    job_id: str = JOB_ID, user: str = Depends(current_user), ctx: Context = Depends(get_context)
) -> dict:
    """The nested levels of a hierarchy job (options.hierarchy) in one small JSON: what hierarchy.json
    says (model, ratio, coarsest, nested, cells, dim) and per level (0 = coarsest) its `elements`,
    `normalized_cut`, `coverage`, `partition` statistics and metric `summary` (from level_L.metrics.json).
    The polygons of a 2D level: GET .../hierarchy/levels/{level}."""
    zf, index = _hierarchy(ctx, user, job_id)
    with zf:
        levels = []
        for entry in index["levels"]:
            rep = json.loads(zf.read(entry["metrics"])) if entry.get("metrics") else {}
            levels.append(
                {
                    "level": entry["level"],
                    "elements": entry["elements"],
                    "normalized_cut": entry.get("normalized_cut"),
                    "coverage": rep.get("coverage"),
                    "partition": rep.get("partition", {}),
                    "summary": rep.get("summary", {}),
                }
            )
    keep = ("cells", "dim", "nested", "model", "ratio", "coarsest", "method", "build_time")
    return {**{k: index[k] for k in keep if k in index}, "levels": levels}


@router.get(
    "/v1/jobs/{job_id}/hierarchy/levels/{level}",
    tags=["jobs"],
    responses={
        **POLYGON_ERRORS,
        404: {"model": ErrorOut, "description": "no such job or level, or a 3D job"},
    },
)
def hierarchy_level(
    job_id: str = JOB_ID,
    level: int = LEVEL,
    user: str = Depends(current_user),
    ctx: Context = Depends(get_context),
) -> dict:
    """One level of a 2D hierarchy job as polygons (as GET /v1/jobs/{id}/polygons), plus per element
    its `parent` (element of level - 1; absent for level 0) and `root` (element of level 0), read from
    the level's labels: the page colours children after their ancestor, so the nesting shows."""
    zf, index = _hierarchy(ctx, user, job_id)
    with zf:
        if index.get("dim") != 2:
            raise NotFound("levels are drawn for 2D meshes only; hierarchy.zip has the 3D level meshes")
        if level >= len(index["levels"]):
            raise NotFound(f"the hierarchy has levels 0..{len(index['levels']) - 1}, not {level}")
        entry = index["levels"][level]
        with tempfile.TemporaryDirectory(prefix="level-") as tmp:
            vtu = Path(tmp) / "level.vtu"
            vtu.write_bytes(zf.read(entry["mesh"]))
            out = element_polygons(vtu)
        labels = np.asarray(json.loads(zf.read(entry["labels"])), dtype=np.int64)
        n = entry["elements"]
        if level > 0:
            out["parent"] = _coarser(labels, json.loads(zf.read(index["levels"][level - 1]["labels"])), n)
        out["root"] = _coarser(labels, json.loads(zf.read(index["levels"][0]["labels"])), n)
    out["level"], out["elements"] = level, n
    return out


def _coarser(labels: np.ndarray, coarse, n: int) -> list[int]:
    """The coarser element of each element (levels are nested: any of its cells tells)."""
    up = np.zeros(n, dtype=np.int64)
    up[labels] = np.asarray(coarse, dtype=np.int64)
    return up.tolist()


@router.get("/v1/meshes/{mesh_id}/polygons", tags=["meshes"], responses=errors(401, 404, 413, 422))
def mesh_polygons(
    mesh_id: str = MESH_ID, user: str = Depends(current_user), ctx: Context = Depends(get_context)
) -> dict:
    """The cells of an uploaded 2D mesh as polygons (`points`, `connectivity` cut by `offsets`), read
    in the same limited child process as the upload: what the page draws under a hierarchy's levels.
    404 for a 3D mesh, 413 above 200,000 cells."""
    with ctx.db.session() as s:
        mesh, _ = visible_mesh(s, user, mesh_id)
    if mesh.info.get("dim") != 2:
        raise NotFound("polygons are drawn for 2D meshes only")
    limit = min(DRAWN_CELLS, ctx.settings.max_cells)
    if int(mesh.info.get("cells", 0)) > limit:
        raise UploadRejected(413, f"the mesh has {mesh.info['cells']} cells; at most {limit} are drawn")
    return upload_polygons(
        ctx.storage.mesh_path(mesh.id, mesh.ext),
        mesh.ext,
        limit,
        ctx.settings.parse_memory_bytes,
        ctx.settings.parse_timeout_s,
    )


@router.get(
    "/v1/jobs/{job_id}/hierarchy/levels/{level}/preview.png",
    tags=["jobs"],
    response_class=FileResponse,
    responses={**errors(401, 404, 409, 422), **binary("image/png", "A picture of the level.")},
)
def hierarchy_level_picture(
    job_id: str = JOB_ID,
    level: int = LEVEL,
    user: str = Depends(current_user),
    ctx: Context = Depends(get_context),
) -> FileResponse:
    """A picture of one level of a hierarchy job, as the job's preview.png (3D: the exploded view):
    drawn from the stored upload and the level's labels the first time, then kept with the results.
    404 when the level does not exist or the mesh was deleted."""
    archive = result_file(ctx, user, job_id, "hierarchy.zip")
    with zipfile.ZipFile(archive) as zf:
        levels = len(json.loads(zf.read("hierarchy.json"))["levels"])
    if level >= levels:
        raise NotFound(f"the hierarchy has levels 0..{levels - 1}, not {level}")
    picture = archive.parent / "web" / f"level_{level}.png"
    if not picture.exists():
        with ctx.db.session() as s:
            job = visible_job(s, user, job_id)
            mesh = s.get(MeshRecord, job.mesh_id)
        path = ctx.storage.mesh_path(mesh.id, mesh.ext) if mesh is not None else None
        if path is None or not path.exists():
            raise NotFound("the job's mesh was deleted: no picture of its levels (hierarchy.zip has them)")
        picture.parent.mkdir(exist_ok=True)
        part = picture.with_name(f"{picture.name}.{uuid.uuid4().hex}.tmp")
        try:
            level_picture(
                path,
                mesh.ext,
                archive,
                level,
                part,
                ctx.settings.parse_memory_bytes,
                ctx.settings.parse_timeout_s,
            )
            os.replace(part, picture)
        finally:
            part.unlink(missing_ok=True)
    return FileResponse(picture, media_type="image/png", filename=f"{job_id}-level_{level}.png")
