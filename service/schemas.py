"""Wire formats (pydantic), separate from the database records."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, PlainSerializer

UTCDateTime = Annotated[
    datetime,
    PlainSerializer(lambda d: d.replace(tzinfo=UTC).isoformat().replace("+00:00", "Z"), return_type=str),
]
JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
Finite = dict(allow_inf_nan=False)


class ErrorOut(BaseModel):
    detail: str = Field(description="What went wrong, in words.")
    field: str | None = Field(None, description="The offending parameter, when one is to blame.")


class FieldError(BaseModel):
    loc: list[str | int] = Field(description="Where: 'body', 'query' or 'path', then the field's path.")
    msg: str
    type: str


class ValidationErrorOut(ErrorOut):
    """Every 422 answer: `detail` in words, `field` the (first) offending parameter (e.g.
    `target_size`, `options.seed`), and for malformed requests each problem in `errors`."""

    errors: list[FieldError] | None = Field(None, description="Each problem, when the request was malformed.")


class MeshOut(BaseModel):
    id: str = Field(
        description="sha256 of the format extension and the uploaded bytes: the same file under the same "
        "extension is the same mesh"
    )
    filename: str | None = None
    size: int
    cells: int
    points: int
    dim: int
    cell_types: dict[str, int]
    lower_dim_cells: dict[str, int] = Field(
        default_factory=dict,
        description="Cells of a lower dimension than the elements (e.g. boundary triangles in a "
        "tetrahedral file), by type: not agglomerated; tagged boundary faces/edges keep their groups.",
    )
    physical_groups: list[int]
    boundary_groups: list[int] = Field(
        default_factory=list, description="tags of the boundary groups (tagged edges in 2D, faces in 3D)"
    )
    boundary: dict | None = Field(
        None,
        description="boundary groups: tag, name, facets on the boundary / inside; untagged boundary facets",
    )
    bbox: list[list[float]]
    surface: dict | None = Field(
        None,
        description="a closed surface (STL, OBJ, PLY, OFF) to fill: triangles, area, enclosed_volume, "
        "oriented, estimated_cells (`cells` is that estimate); jobs on it need options.fill",
    )
    check: dict | None = Field(
        None,
        description="the `magnet check` report: pieces, boundary loops/shells, holes, orientation fixes, folded, "
        "duplicate/unused points, hanging nodes, issues [{kind, severity, count, ids, message}] and a verdict",
    )
    created_at: UTCDateTime


class JobOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)  # JSON as sent: "8" is no k (forms: lax)
    seed: int | None = Field(None, ge=0, le=2**31 - 1)
    absorb_fraction: float | None = Field(
        None, ge=0, lt=1, **Finite, description="absorb parts smaller than this x mean part size"
    )
    hole_policy: str | None = Field(None, max_length=40, description="split | error")
    physical_tag: str | None = Field(
        None,
        max_length=200,
        pattern=r"^[^\x00-\x1f\x7f]*$",
        description="cell-data name of the physical groups (default: the first of gmsh:physical, "
        "CellEntityIds, cell_tags, medit:ref, physical, material, tag, physical_group)",
    )
    method: str | None = Field(None, max_length=40, description="METIS kway | recursive")
    boundary_tag: int | None = Field(
        None,
        ge=0,
        le=2**31 - 1,
        description="lymph bc_tag of boundary edges without a boundary group (default 1)",
    )
    weld: float | None = Field(
        None,
        ge=0,
        **Finite,
        description="merge points closer than this distance first (duplicate points that split the mesh)",
    )
    size_measure: str | None = Field(
        None,
        max_length=40,
        description="part size for target-size / mult-factor: centroids (default) | vertices",
    )
    threshold: int | None = Field(
        None, ge=2, le=10**6, description="coarsest graph size, mode multilevel (200)"
    )
    hierarchy: bool | None = Field(
        None, description="also keep every nested level (GET /v1/jobs/{id}/hierarchy)"
    )
    ratio: float | None = Field(
        None,
        ge=2,
        le=1e6,
        **Finite,
        description="with hierarchy: the job's agglomeration is the finest level and coarser ones have "
        "this many times fewer elements per level, any model (as `magnet hierarchy`)",
    )
    coarsest: int | None = Field(
        None, ge=1, le=10**9, description="with ratio: at most this many elements on the coarsest level (10)"
    )
    finest: str | None = Field(
        None,
        max_length=40,
        description="with hierarchy: nested levels of their own from the cells (as `magnet hierarchy "
        "--finest`), the finest level made by aggregation (rtree, no ratio) | cuts | quality (rtree, no "
        "ratio) | nested (rtree, no ratio)",
    )
    boxfit: bool | None = Field(
        None,
        description="with hierarchy: nested levels of their own from the cells, then boundary units moved "
        "towards tighter boxes (as `magnet hierarchy --boxfit`)",
    )
    groups: bool | None = Field(
        None,
        description="with a hierarchy of its own (ratio, finest or boxfit): no element of any level crosses "
        "a physical group (as `magnet hierarchy --groups`; rtree, metis, kmeans)",
    )
    keep_rings: bool | None = Field(
        None,
        description="with a hierarchy of its own, 3D: keep elements with a handle (rings around a tunnel) "
        "instead of cutting them (as `magnet hierarchy --keep-rings`; faster)",
    )
    kappa: list[Annotated[float, Field(gt=0, **Finite)]] | None = Field(
        None,
        min_length=2,
        max_length=3,
        description="with a hierarchy of its own: the diagonal diffusion tensor [kx, ky(, kz)] the levels are "
        "cut for (as `magnet hierarchy --kappa`; rtree)",
    )
    allow_extra: bool | None = Field(
        None,
        description="with k: keep every connected fragment of a part as an element (more than k); "
        "default false: exactly k elements, or a 422 saying why k cannot be met",
    )
    keep_groups: bool | None = Field(
        None, description="refiner: cuts prefer physical-group interfaces (default: on for sage-hetero)"
    )
    fill: bool | None = Field(
        None,
        description="the mesh is a closed surface (STL, OBJ, PLY, OFF): fill it with tetrahedra first, "
        "keeping its triangles",
    )
    fill_remesh: bool | None = Field(None, description="with fill: re-mesh the surface first")
    fill_size: float | None = Field(
        None,
        gt=0,
        le=1,
        **Finite,
        description="with fill: re-mesh size, fraction of the bounding-box diagonal",
    )
    fill_size_abs: float | None = Field(
        None, gt=0, **Finite, description="with fill: re-mesh size in the file's own length unit"
    )
    fill_max_cells: int | None = Field(
        None,
        ge=1,
        le=10**9,
        description="with fill: refuse beyond this estimated number of tetrahedra (5,000,000)",
    )


class JobParams(BaseModel):
    """Agglomeration parameters, as for `magnet agglomerate`; the library validates their meaning."""

    model_config = ConfigDict(extra="forbid", strict=True)  # JSON as sent: "8" is no k (forms: lax)
    model: str | None = Field(
        None, max_length=40, description="metis | kmeans | rtree | sage-base | sage-hetero | rl-partitioner"
    )
    mode: str | None = Field(
        None,
        max_length=40,
        description="kway | nref | target-size | mult-factor | segregated | coarsen | multilevel "
        "(default: the one the size given implies: k kway, nref nref, target_size target-size, "
        "mult_factor mult-factor; with subset coarsen)",
    )
    k: int | None = Field(None, ge=1, description="number of elements (kway): exactly k unless allow_extra")
    nref: int | None = Field(
        None, ge=0, description="number of refinements: exactly 2^nref elements unless allow_extra"
    )
    target_size: float | None = Field(None, gt=0, **Finite, description="largest element diameter")
    mult_factor: float | None = Field(
        None, gt=0, le=1, **Finite, description="element diameter / mesh diameter"
    )
    subset: list[Annotated[int, Field(ge=0, le=2**62)]] | None = Field(
        None, description="cell ids to agglomerate (coarsen mode)"
    )
    refiner: str | None = Field(None, max_length=40, description="fm | rl-refiner (null: none)")
    options: JobOptions | None = None

    def library_params(self) -> dict:
        """The dict models.api.validate_params takes (unset fields left out)."""
        return self.model_dump(exclude_none=True)


class JobCreate(JobParams):
    mesh_id: str = Field(min_length=1, max_length=64)


class JobResult(BaseModel):
    elements: int | None = None
    parts_split: int | None = None
    fragments_absorbed: int | None = None
    holes_split: int | None = None
    timings: dict[str, float] = {}
    fill: dict | None = None


class JobOut(BaseModel):
    id: str
    status: JobStatus
    progress: float = Field(ge=0, le=1)
    stage: str | None = None
    created_at: UTCDateTime
    started_at: UTCDateTime | None = None
    finished_at: UTCDateTime | None = None
    error: str | None = None
    result: JobResult | None = None
    mesh_id: str
    params: dict
    model_version: str
    queue: str
    attempts: int
    cached: bool = Field(description="served from an identical earlier or in-flight job, not recomputed")


class JobList(BaseModel):
    items: list[JobOut]
    total: int
    limit: int
    offset: int


class ModelCard(BaseModel):
    model_config = ConfigDict(extra="allow")
    name: str
    dimension: int | str | list[int] | None = None
    modes: list[str] = []
    description: str = ""
    version: str | None = None


class Health(BaseModel):
    status: str
    checks: dict[str, str] = {}
