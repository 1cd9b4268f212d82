"""The web page at `/` (plain HTML/CSS/JS shipped in service/web, nothing fetched at run time) and
the one JSON it needs beyond the API: the polygons of a finished 2D job, for drawing it as SVG."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from fastapi import APIRouter, Depends, FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from service.auth import current_user
from service.context import Context, get_context
from service.jobs import NotFound
from service.routers.jobs import JOB_ID, result_file
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
def index() -> FileResponse:
    """The web page (no auth: the page itself asks for the API key and sends it with every call)."""
    return FileResponse(
        WEB_DIR / "index.html",
        media_type="text/html",
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
