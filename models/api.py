"""The library's entry points for callers that run whole jobs (the CLI, the Celery worker).

Torch-free at import time: the service imports this module (validation, model cards, mesh
inspection) and must never import torch. Neural partitioners are loaded lazily by name.

- inspect_mesh(path, physical_tag=None) -> {"cells", "points", "dim", "cell_types": {name: count},
  "physical_groups": [int], "bbox": [[min...], [max...]], "boundary_groups": [int], "boundary":
  models.mesh.boundary.summary}; raises MeshError.
- validate_params(params, mesh_info=None) -> normalized params dict; raises ParameterError whose
  message names the field. Keys: model, mode, k, nref, target_size, mult_factor, subset (list of
  cell ids), refiner (fm | rl-refiner | null), options {seed, absorb_fraction, hole_policy,
  physical_tag, method, boundary_tag (lymph bc_tag of boundary edges without a boundary group,
  default 1), size_measure ("centroids": a part's size is the largest distance between its cell
  centroids, the paper's measure, default; "vertices": between its vertices), threshold (coarsest
  graph size of mode multilevel, default 200), hierarchy (keep every nested level), ratio / coarsest
  (with hierarchy: nested levels of their own at this coarsening ratio, as `magnet hierarchy`), finest /
  boxfit (with hierarchy: levels of their own from the cells, as `magnet hierarchy --finest F --boxfit`), weld (merge
  points closer than this first)}.
- run_job(mesh_path, out_dir, params, progress=None, should_cancel=None) -> summary dict
  {"elements", "parts_split", "fragments_absorbed", "timings": {stage: seconds}, "outputs": {kind: filename}}
  writing into out_dir: mesh.vtu, metrics.json, labels.json, preview.png, and for 2D meshes
  lymph.json + lymph.mat. progress(fraction 0..1, stage name) is called along the way;
  should_cancel() returning True stops the job with JobCancelled.
- list_models() -> [{"name", "dimension", "modes", "description", "version"}]
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

from models.params import (  # noqa: F401  (re-exported: the service and worker use them)
    MAX_SUBSET,
    MODEL_CARDS,
    MODEL_VERSION,
    MODES,
    REFINERS,
    list_models,
    validate_params,
)


class JobCancelled(Exception):
    """Raised inside run_job when should_cancel() returned True."""


def inspect_mesh(path: str | os.PathLike, physical_tag: str | None = None, check: bool = False) -> dict:
    """Read and validate a mesh; return its summary (MeshError if it is not a valid mesh).
    check: add the `magnet check` report (models.mesh.check.mesh_report) under "check"."""
    from models.errors import MagnetError
    from models.mesh.fill import is_surface_file
    from models.mesh.read import describe
    from models.mesh.sandbox import read_mesh_safe as read_mesh

    try:
        mesh = read_mesh(path, physical_tag=physical_tag)
    except MagnetError as exc:
        if not is_surface_file(path):
            raise
        from models.mesh.fill import open_surface_refusal

        refused = open_surface_refusal(path, exc)
        if refused is not exc:  # (neither a mesh nor a surface to fill: both said, as `check` says)
            raise refused from None
        from models.mesh.build import FILL_HINT

        if FILL_HINT not in str(exc):  # (unreadable, not a curved surface: as `check`)
            raise
        return _inspect_surface(path)
    info = describe(mesh)
    if check:
        from models.mesh.check import mesh_report, named

        info["check"] = named(mesh_report(mesh), path)
    return info


def _inspect_surface(path) -> dict:
    """inspect_mesh of a closed surface to be filled (MeshError, saying where, if it is not closed)."""
    from models.mesh.fill import check_closed, estimate_cells, read_surface

    s = read_surface(path)
    check_closed(s)
    est = estimate_cells(s)
    return {
        "cells": est,
        "points": len(s.points),
        "dim": 3,
        "cell_types": {"triangle": len(s.triangles)},
        "physical_groups": [],
        "bbox": s.info["bbox"],
        "boundary_groups": [],
        "surface": {k: s.info[k] for k in ("triangles", "area", "enclosed_volume", "oriented")}
        | {"estimated_cells": est},
    }


def run_job(
    mesh_path: str | os.PathLike,
    out_dir: str | os.PathLike,
    params: dict,
    progress: Callable[[float, str], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
    warn: Callable[[str], None] | None = None,
) -> dict:
    """Run one agglomeration job from a mesh file to the output files in out_dir."""
    from models import pipeline
    from models.agglomeration import run

    p = validate_params(params)
    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)

    def tick(frac: float, stage: str) -> None:
        if should_cancel is not None and should_cancel():
            raise JobCancelled("the job was cancelled")
        if progress is not None:
            progress(frac, stage)

    t0 = time.perf_counter()
    tick(0.0, "fill" if p["options"].get("fill") else "read")
    result = run(mesh_path, params, progress=tick, warn=warn, untrusted=True)  # uploads: always sandboxed
    res = result.result
    mesh, p, o = res.mesh, result.params, result.params["options"]
    files = {"mesh": "mesh.vtu", "metrics": "metrics.json", "labels": "labels.json", "preview": "preview.png"}
    if mesh.dim == 2:
        files["lymph"] = "lymph.json"
        files["lymph_mat"] = "lymph.mat"
    join = lambda name: os.path.join(out_dir, name)  # noqa: E731
    pipeline.write_outputs(
        res,
        vtu=join(files["mesh"]),
        labels=join(files["labels"]),
        plot=join(files["preview"]),
        lymph=[join("lymph.json"), join("lymph.mat")] if mesh.dim == 2 else None,
        metrics=join(files["metrics"]),
        extra={"params": p, "model_version": MODEL_VERSION},
        boundary_tag=o["boundary_tag"],
    )
    if o["hierarchy"]:
        tick(0.95, "hierarchy")
        _write_hierarchy_zip(res, out_dir, o["boundary_tag"], p["model"], o)
        files["hierarchy"] = "hierarchy.zip"
    tick(1.0, "done")
    s = res.summary()
    s["timings"]["total"] = round(time.perf_counter() - t0, 4)
    s["outputs"] = files
    if o.get("fill"):
        s["fill"] = mesh.meta.get("fill")
    return s


def _write_hierarchy_zip(
    res, out_dir: str, boundary_tag: int, model: str | None = None, o: dict | None = None
) -> None:
    """Every nested level into out_dir/hierarchy.zip (flat archive; lymph structs per level in 2D).
    With options.ratio: a hierarchy of its own with the job's model (models.hierarchy.nested.build_hierarchy,
    as `magnet hierarchy`), aggregation operators included."""
    import shutil
    import tempfile
    import zipfile

    from models import pipeline

    tmp = tempfile.mkdtemp(prefix="hierarchy-", dir=out_dir)
    try:
        own = o is not None and (o.get("finest") is not None or bool(o.get("boxfit")))
        if own or (o is not None and o.get("ratio") is not None):
            import numpy as np

            from models.hierarchy.nested import build_hierarchy, write_hierarchy

            # options.finest / boxfit: levels of their own from the cells, as `magnet hierarchy
            # --finest F --boxfit`; options.ratio alone: the job's agglomeration is the finest level
            levels, info = build_hierarchy(
                res.mesh,
                res.data,
                model=model or "rtree",
                ratio=o["ratio"],
                coarsest=o["coarsest"] or 10,
                seed=o["seed"],
                model_options=({k: o[k] for k in ("finest", "boxfit") if o.get(k)} if own else {})
                | ({"rings": False} if o.get("keep_rings") else {}),
                finest=None if own else res.agglomeration.labels,
                groups=bool(o.get("groups")),
                kappa=None if o.get("kappa") is None else np.asarray(o["kappa"], dtype=np.float64),
            )
            write_hierarchy(
                tmp,
                res.mesh,
                res.data,
                levels,
                metrics=True,
                lymph=res.mesh.dim == 2,
                boundary=res.boundary,
                boundary_tag=boundary_tag,
                merged=info.pop("merged"),
                extra={
                    k: info[k]
                    for k in (
                        "model",
                        "finest",
                        "boxfit",
                        "ratio",
                        "coarsest",
                        "kappa",
                        "method",
                        "build_time",
                        "report",
                        "notes",
                        "stretch",
                    )
                    if k in info
                },
            )
        else:
            pipeline.write_hierarchy(
                res, tmp, metrics=True, lymph=res.mesh.dim == 2, boundary_tag=boundary_tag
            )
        part = os.path.join(out_dir, "hierarchy.zip.tmp")
        with zipfile.ZipFile(part, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            for name in sorted(os.listdir(tmp)):
                zf.write(os.path.join(tmp, name), arcname=name)
        os.replace(part, os.path.join(out_dir, "hierarchy.zip"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
