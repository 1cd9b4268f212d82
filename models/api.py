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
  (with hierarchy: nested levels of their own at this coarsening ratio, as `magnet hierarchy`), weld (merge
  points closer than this first)}.
- run_job(mesh_path, out_dir, params, progress=None, should_cancel=None) -> summary dict
  {"elements", "parts_split", "fragments_absorbed", "timings": {stage: seconds}, "outputs": {kind: filename}}
  writing into out_dir: mesh.vtu, metrics.json, labels.json, preview.png, and for 2D meshes
  lymph.json + lymph.mat. progress(fraction 0..1, stage name) is called along the way;
  should_cancel() returning True stops the job with JobCancelled.
- list_models() -> [{"name", "dimension", "modes", "description", "version"}]
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable

from models.errors import ParameterError

MODEL_VERSION = "0.1.0"
MODES = ("kway", "nref", "target-size", "mult-factor", "segregated", "coarsen", "multilevel")
REFINERS = ("fm", "rl-refiner")
MAX_SUBSET = 50_000_000

MODEL_CARDS = [
    {
        "name": "metis",
        "dimension": [2, 3],
        "modes": list(MODES),
        "description": "METIS multilevel graph partitioning (pymetis): k-way or recursive bisection, cell measures as integer node weights, contiguous parts.",
    },
    {
        "name": "kmeans",
        "dimension": [2, 3],
        "modes": list(MODES),
        "description": "k-means (scikit-learn) on cell centroids, seeded and deterministic; parts split into connected components.",
    },
    {
        "name": "rtree",
        "dimension": [2, 3],
        "modes": list(MODES),
        "description": "R-tree-like nested geometric agglomeration: box cuts along the longest extent at measure-weighted quantiles, exact counts, every part connected; deterministic and fast (magnet hierarchy builds nested levels with it).",
    },
    {
        "name": "sage-base",
        "dimension": [2, 3],
        "modes": [m for m in MODES if m != "kway"],
        "description": "SAGE-Base graph neural network: recursive bisection minimizing the expected normalized cut, batched level by level (2D 64/32 or 3D 128/64 units chosen from the mesh).",
    },
    {
        "name": "sage-hetero",
        "dimension": [2, 3],
        "modes": [m for m in MODES if m != "kway"],
        "description": "SAGE-Heterogeneous graph neural network: like SAGE-Base with the physical group as a feature and a penalty for mixing two groups.",
    },
    {
        "name": "rl-partitioner",
        "dimension": [2, 3],
        "modes": ["nref", "target-size", "mult-factor", "segregated", "coarsen", "multilevel"],
        "description": "RL partitioner (A2C, models/weights/rl-partitioner-2d.md and -3d.md, picked by the mesh's dimension): grows one side from a minimum-degree seed; meant for the coarsest graphs of mode multilevel (slow on a whole fine mesh).",
    },
]
# Refiners (field `refiner`): every model's bisections in nref / target-size / mult-factor /
# segregated / coarsen / multilevel; k-way mode (metis, kmeans) takes `fm` only.
for _card in MODEL_CARDS:
    _card["refiners"] = list(REFINERS)
    _card["combinations"] = [
        {"mode": m, "refiners": ["fm"] if m == "kway" else list(REFINERS)} for m in _card["modes"]
    ]
del _card


class JobCancelled(Exception):
    """Raised inside run_job when should_cancel() returned True."""


def list_models() -> list[dict]:
    return [dict(card, version=MODEL_VERSION) for card in MODEL_CARDS]


def inspect_mesh(path: str | os.PathLike, physical_tag: str | None = None, check: bool = False) -> dict:
    """Read and validate a mesh; return its summary (MeshError if it is not a valid mesh).
    check: add the `magnet check` report (models.mesh.check.mesh_report) under "check"."""
    from models.mesh.read import describe, read_mesh

    mesh = read_mesh(path, physical_tag=physical_tag)
    info = describe(mesh)
    if check:
        from models.mesh.check import mesh_report

        info["check"] = mesh_report(mesh)
    return info


def _int(params: dict, name: str, lo: int | None = None, hi: int | None = None) -> int | None:
    v = params.get(name)
    if v is None:
        return None
    if isinstance(v, bool) or not (isinstance(v, int) or (isinstance(v, float) and v.is_integer())):
        raise ParameterError(f"{name} must be an integer, got {v!r}")
    v = int(v)
    if lo is not None and v < lo:
        raise ParameterError(f"{name} must be >= {lo}, got {v}")
    if hi is not None and v > hi:
        raise ParameterError(f"{name} must be <= {hi}, got {v}")
    return v


def _float(params: dict, name: str, lo_open: float | None = None, hi: float | None = None) -> float | None:
    v = params.get(name)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ParameterError(f"{name} must be a number, got {v!r}")
    v = float(v)
    if not math.isfinite(v):
        raise ParameterError(f"{name} must be finite, got {v}")
    if lo_open is not None and v <= lo_open:
        raise ParameterError(f"{name} must be > {lo_open}, got {v}")
    if hi is not None and v > hi:
        raise ParameterError(f"{name} must be <= {hi}, got {v}")
    return v


def validate_params(params: dict, mesh_info: dict | None = None) -> dict:
    """Check and normalize job parameters (before any work is queued)."""
    if not isinstance(params, dict):
        raise ParameterError("parameters must be a JSON object")
    known = {"model", "mode", "k", "nref", "target_size", "mult_factor", "subset", "refiner", "options"}
    unknown = set(params) - known
    if unknown:
        raise ParameterError(f"unknown parameter(s): {sorted(unknown)}")
    model = params.get("model", "metis")
    names = [c["name"] for c in MODEL_CARDS]
    if model not in names:
        raise ParameterError(f"model must be one of {names}, got {model!r}")
    mode = params.get("mode", "kway")
    if mode not in MODES:
        raise ParameterError(f"mode must be one of {list(MODES)}, got {mode!r}")
    k = _int(params, "k", lo=1)
    nref = _int(params, "nref", lo=0, hi=30)
    target_size = _float(params, "target_size", lo_open=0.0)
    mult_factor = _float(params, "mult_factor", lo_open=0.0, hi=1.0)
    subset = params.get("subset")
    if subset is not None:
        if not isinstance(subset, list) or not subset:
            raise ParameterError("subset must be a non-empty list of cell ids")
        if len(subset) > MAX_SUBSET or not all(
            isinstance(i, int) and not isinstance(i, bool) for i in subset
        ):
            raise ParameterError("subset must be a list of integer cell ids")
        if min(subset) < 0:
            raise ParameterError(f"subset has negative cell ids, e.g. {min(subset)}")
    refiner = params.get("refiner")
    if refiner == "none":
        refiner = None
    if refiner is not None and refiner not in REFINERS:
        raise ParameterError(f"refiner must be one of {list(REFINERS)} or null, got {refiner!r}")
    if refiner == "rl-refiner" and (mode == "kway" or (mode == "coarsen" and k is not None)):
        raise ParameterError("refiner 'rl-refiner' refines bisections only; k-way mode takes refiner 'fm'")
    if mode == "multilevel" and all(v is None for v in (nref, target_size, mult_factor)):
        raise ParameterError("mode 'multilevel' needs one of nref, target_size, mult_factor")
    opts = params.get("options") or {}
    if not isinstance(opts, dict):
        raise ParameterError("options must be an object")
    known_opts = {
        "seed",
        "absorb_fraction",
        "hole_policy",
        "physical_tag",
        "method",
        "boundary_tag",
        "size_measure",
        "threshold",
        "hierarchy",
        "weld",
        "ratio",
        "coarsest",
    }
    if set(opts) - known_opts:
        raise ParameterError(f"unknown option(s): {sorted(set(opts) - known_opts)}")
    seed = _int(opts, "seed", lo=0, hi=2**31 - 1) or 0
    absorb = opts.get("absorb_fraction", 0.0)
    if isinstance(absorb, bool) or not isinstance(absorb, int | float) or not (0 <= absorb < 1):
        raise ParameterError(f"options.absorb_fraction must be a number in [0, 1), got {absorb!r}")
    hole_policy = opts.get("hole_policy", "split")
    if hole_policy not in ("split", "error"):
        raise ParameterError(f"options.hole_policy must be 'split' or 'error', got {hole_policy!r}")
    physical_tag = opts.get("physical_tag")
    if physical_tag is not None and (
        not isinstance(physical_tag, str) or not physical_tag or len(physical_tag) > 200
    ):
        raise ParameterError("options.physical_tag must be a non-empty string")
    boundary_tag = _int(opts, "boundary_tag", lo=0, hi=2**31 - 1)
    boundary_tag = 1 if boundary_tag is None else boundary_tag
    threshold = _int(opts, "threshold", lo=2, hi=1_000_000)
    threshold = 200 if threshold is None else threshold
    hierarchy = opts.get("hierarchy", False)
    if hierarchy in ("true", "false"):  # form fields arrive as strings
        hierarchy = hierarchy == "true"
    if not isinstance(hierarchy, bool):
        raise ParameterError(f"options.hierarchy must be true or false, got {hierarchy!r}")
    ratio = _float(opts, "ratio")
    if ratio is not None and ratio < 2:
        raise ParameterError(f"options.ratio must be >= 2 (coarsening ratio per level), got {ratio}")
    coarsest = _int(opts, "coarsest", lo=1, hi=10**9)
    if (ratio is not None or coarsest is not None) and not hierarchy:
        raise ParameterError("options.ratio and options.coarsest go with options.hierarchy = true")
    if hierarchy and ratio is None and (mode == "kway" or (mode == "coarsen" and k is not None)):
        raise ParameterError(
            "options.hierarchy needs a recursive mode (nref, target-size, mult-factor, segregated, "
            "coarsen or multilevel), not k-way, or options.ratio (a hierarchy of its own, like "
            "`magnet hierarchy`)"
        )
    method = opts.get("method", "kway")
    if method not in ("kway", "recursive"):
        raise ParameterError(f"options.method must be 'kway' or 'recursive', got {method!r}")
    weld = _float(opts, "weld")
    if weld is not None and weld < 0:
        raise ParameterError(f"options.weld must be >= 0 (a distance), got {weld}")
    size_measure = opts.get("size_measure", "centroids")
    if size_measure not in ("centroids", "vertices"):
        raise ParameterError(f"options.size_measure must be 'centroids' or 'vertices', got {size_measure!r}")

    need = {
        "kway": ("k", k),
        "nref": ("nref", nref),
        "target-size": ("target_size", target_size),
        "mult-factor": ("mult_factor", mult_factor),
        "segregated": ("mult_factor", mult_factor),
    }
    if mode in need and need[mode][1] is None:
        raise ParameterError(f"{need[mode][0]} is required for mode {mode!r}")
    if mode == "coarsen":
        if subset is None:
            raise ParameterError("subset is required for mode 'coarsen'")
        if all(v is None for v in (k, nref, target_size, mult_factor)):
            raise ParameterError("mode 'coarsen' needs one of k, nref, target_size, mult_factor")
    if model in ("sage-base", "sage-hetero", "rl-partitioner") and (
        mode == "kway" or (mode == "coarsen" and k is not None)
    ):
        raise ParameterError(
            f"model {model!r} has no direct k-way mode; use nref, target-size or mult-factor"
        )

    if mesh_info is not None:
        n = int(mesh_info["cells"])
        n_work = n if subset is None else len(set(subset))
        if subset is not None and max(subset) >= n:
            raise ParameterError(
                f"subset has unknown cell ids (the mesh has cells 0..{n - 1}), e.g. {max(subset)}"
            )
        if k is not None and k > n_work:
            raise ParameterError(f"k = {k} is larger than the number of cells to agglomerate ({n_work})")
        if nref is not None and 2**nref > n_work:
            raise ParameterError(f"nref = {nref} asks for 2^{nref} elements, more than the {n_work} cells")
        if mode == "segregated" and not mesh_info.get("physical_groups"):
            raise ParameterError("mode 'segregated' needs a mesh with physical groups")

    return {
        "model": model,
        "mode": mode,
        "k": k,
        "nref": nref,
        "target_size": target_size,
        "mult_factor": mult_factor,
        "subset": subset,
        "refiner": refiner,
        "options": {
            "seed": seed,
            "absorb_fraction": float(absorb),
            "hole_policy": hole_policy,
            "physical_tag": physical_tag,
            "method": method,
            "boundary_tag": boundary_tag,
            "size_measure": size_measure,
            "threshold": threshold,
            "hierarchy": hierarchy,
            "weld": weld,
            "ratio": ratio,
            "coarsest": coarsest,
        },
    }


def run_job(
    mesh_path: str | os.PathLike,
    out_dir: str | os.PathLike,
    params: dict,
    progress: Callable[[float, str], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> dict:
    """Run one agglomeration job from a mesh file to the output files in out_dir."""
    from models import pipeline
    from models.mesh.read import read_mesh

    p = validate_params(params)
    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)

    def tick(frac: float, stage: str) -> None:
        if should_cancel is not None and should_cancel():
            raise JobCancelled("the job was cancelled")
        if progress is not None:
            progress(frac, stage)

    t0 = time.perf_counter()
    tick(0.0, "read")
    mesh = read_mesh(mesh_path, physical_tag=p["options"]["physical_tag"], weld=p["options"]["weld"])
    t_read = time.perf_counter() - t0
    validate_params(
        params, {"cells": mesh.n_cells, "physical_groups": mesh.physical_groups(), "dim": mesh.dim}
    )
    o = p["options"]
    model_options = {"method": o["method"]} if p["model"] == "metis" else None
    res = pipeline.run(
        mesh,
        model=p["model"],
        mode=p["mode"],
        k=p["k"],
        nref=p["nref"],
        target_size=p["target_size"],
        mult_factor=p["mult_factor"],
        subset=p["subset"],
        absorb_fraction=o["absorb_fraction"],
        hole_policy=o["hole_policy"],
        seed=o["seed"],
        model_options=model_options,
        progress=tick,
        size_measure=o["size_measure"],
        refiner=p["refiner"],
        threshold=o["threshold"],
        record_levels=o["hierarchy"] and o["ratio"] is None,
    )
    res.timings = {"read": t_read, **res.timings}
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
        if o is not None and o.get("ratio") is not None:
            from models.hierarchy.nested import build_hierarchy, write_hierarchy

            levels, info = build_hierarchy(
                res.mesh,
                res.data,
                model=model or "rtree",
                ratio=o["ratio"],
                coarsest=o["coarsest"] or 10,
                seed=o["seed"],
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
                extra={k: info[k] for k in ("model", "ratio", "coarsest", "method", "build_time", "report")},
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
