"""The Python API (`from models import agglomerate, build_hierarchy, read_mesh, check`): the one
way in. The CLI, the worker (models.api.run_job) and the service call these functions.

A mesh is given as a path, a `meshio.Mesh`, a VTK or pyvista unstructured grid (duck-typed: no
pyvista needed), a `models.mesh.container.Mesh`, or arrays: `points=` plus `cells=` as a list of
(meshio cell type, connectivity) blocks (and `tags=`, one array per block, for physical groups).
Keywords are the CLI's and the service's, checked by the one validation they share
(models.params.validate_params): the same errors, word for word.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TYPE_CHECKING

from models.errors import MeshError, ParameterError
from models.params import shown, validate_params

if TYPE_CHECKING:
    import meshio

    from models.mesh.container import Mesh, PolyMesh
    from models.pipeline import Result

# the slow case a user should hear about before waiting (one line on stderr, see docs/python.md)
SLOW_CELLS = 2_000


def read_mesh(
    source=None,
    *,
    points=None,
    cells=None,
    tags=None,
    physical_tag: str | None = None,
    weld: float | None = None,
    untrusted: bool = False,
) -> Mesh:
    """The validated, positively oriented `Mesh` of any accepted source (MeshError if invalid).
    A path is read by native readers (VTK, HDF5, netCDF) in a forked child with limits, so a crash
    is a MeshError; untrusted=True (uploads: the service and the worker) reads every file so."""
    from models.mesh.container import Mesh
    from models.mesh.read import mesh_from_meshio
    from models.mesh.sandbox import read_mesh_cli, read_mesh_safe

    read_file = read_mesh_safe if untrusted else read_mesh_cli

    if source is None:
        if points is None or cells is None:
            raise ParameterError(
                "give a mesh: a path, a meshio.Mesh, a VTK or pyvista unstructured grid, or points= and cells="
            )
        return mesh_from_meshio(
            _meshio_from_arrays(points, cells, tags), physical_tag=physical_tag, weld=weld
        )
    if points is not None or cells is not None:
        raise ParameterError("give either a mesh or points= and cells=, not both")
    if isinstance(source, str | os.PathLike):
        return read_file(source, physical_tag=physical_tag, weld=weld)
    if isinstance(source, Mesh):
        return source
    if hasattr(source, "GetCellTypesArray") or hasattr(source, "celltypes"):  # VTK, pyvista
        return mesh_from_meshio(_meshio_from_grid(source), physical_tag=physical_tag, weld=weld, owned=True)
    if isinstance(getattr(source, "cells", None), list) and hasattr(source, "points"):  # meshio.Mesh
        return mesh_from_meshio(source, physical_tag=physical_tag, weld=weld)
    raise ParameterError(
        f"cannot read {'an' if type(source).__name__[:1].lower() in 'aeiou' else 'a'} {type(source).__name__} as a mesh: give a path, a meshio.Mesh, a VTK or pyvista "
        "unstructured grid, or points= and cells="
    )


def check(source=None, *, points=None, cells=None, tags=None, physical_tag=None, weld=None) -> dict:
    """The `magnet check` report of a mesh: {verdict: ok | warnings | error, issues: [...], ...}."""
    from models.mesh.check import check_file, mesh_report

    if isinstance(source, str | os.PathLike):
        if points is not None or cells is not None or tags is not None:
            raise ParameterError("give either a mesh or points= and cells=, not both")
        return check_file(source, physical_tag=physical_tag, weld=weld)
    return mesh_report(
        read_mesh(source, points=points, cells=cells, tags=tags, physical_tag=physical_tag, weld=weld)
    )


def agglomerate(
    source=None,
    *,
    points=None,
    cells=None,
    tags=None,
    model: str = "metis",
    mode: str | None = None,
    k: int | None = None,
    nref: int | None = None,
    target_size: float | None = None,
    mult_factor: float | None = None,
    subset=None,
    refiner: str | None = None,
    physical_tag: str | None = None,
    weld: float | None = None,
    seed: int = 0,
    absorb_fraction: float = 0.0,
    hole_policy: str = "split",
    method: str = "kway",
    size_measure: str = "centroids",
    threshold: int = 200,
    keep_groups: bool | None = None,
    allow_extra: bool = False,
    boundary_tag: int = 1,
    hierarchy: bool = False,
    metrics: bool = True,
    progress: Callable[[float, str], None] | None = None,
    warn: Callable[[str], None] | None = None,
    untrusted: bool = False,
) -> Agglomeration:
    """Agglomerate a mesh into polygons (2D) or polyhedra (3D).

    The mode follows from the size given when `mode` is None (k: kway, nref: nref, target_size:
    target-size, mult_factor: mult-factor; with a subset: coarsen). k gives exactly k elements
    unless allow_extra. hierarchy: keep the nested levels of a recursive mode (result.write_hierarchy).
    metrics: compute the metrics now (else on first use of .metrics). warn(line): told of slow runs."""
    for name, fn in (("progress", progress), ("warn", warn)):
        if fn is not None and not callable(fn):
            raise ParameterError(f"{name} must be a function (or None), got a {type(fn).__name__}")
    if not isinstance(metrics, bool):
        raise ParameterError(f"metrics must be True or False, got a {type(metrics).__name__}")
    if subset is not None:
        import numpy as np

        try:
            subset = np.asarray(subset)
        except ValueError:
            raise ParameterError("subset must be a list of cell ids") from None
        subset = subset.tolist() if subset.ndim == 1 and np.issubdtype(subset.dtype, np.integer) else subset
    params = {
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
            "absorb_fraction": absorb_fraction,
            "hole_policy": hole_policy,
            "physical_tag": physical_tag,
            "method": method,
            "boundary_tag": boundary_tag,
            "size_measure": size_measure,
            "threshold": threshold,
            "hierarchy": hierarchy,
            "weld": weld,
            "allow_extra": allow_extra,
            "keep_groups": keep_groups,
        },
    }
    params = {key: v for key, v in params.items() if v is not None}
    params["options"] = {key: v for key, v in params["options"].items() if v is not None}
    try:
        result = run(
            source,
            params,
            points=points,
            cells=cells,
            tags=tags,
            metrics=metrics,
            progress=progress,
            warn=warn,
            untrusted=untrusted,
        )
    except ParameterError as exc:  # (the service's options.seed is this function's seed)
        if "options." not in str(exc) and not str(getattr(exc, "field", None) or "").startswith("options."):
            raise
        raise _own_words(exc) from None
    said = count_note(result.summary(), hierarchy)
    if said:  # (the CLI says it itself)
        (warn or _stderr)(said)
    if result.mesh.meta.get("dropped_cells"):  # (the CLI says it itself; here, the one call)
        from models.mesh.dropped import dropped_sentence

        (warn or _stderr)(
            f"{dropped_sentence(result.mesh.meta)}: labels holds the {result.mesh.n_cells:,} cells read, "
            "input_labels one per cell given (-1 for those)"
        )
    return result


def _subset_as_read(mesh, p: dict) -> dict:
    """Validated params with their subset (cell ids of the file, as labels.json numbers them, checked
    against the file's count) as ids of the cells read, where the read left a few bad cells out;
    those among the subset are left out of it too."""
    if not mesh.meta.get("dropped_cells") or not p.get("subset"):
        return p
    from models.mesh.dropped import read_ids

    mapped = read_ids(mesh.meta, p["subset"])
    if not (mapped >= 0).any():
        raise ParameterError(
            f"every cell of the subset ({len(p['subset']):,}) is among the bad cells the read left out: "
            "give the ids of cells to agglomerate"
        )
    return {**p, "subset": mapped[mapped >= 0].tolist()}


def run(
    source,
    params: dict,
    *,
    points=None,
    cells=None,
    tags=None,
    metrics: bool = True,
    progress: Callable[[float, str], None] | None = None,
    warn: Callable[[str], None] | None = None,
    untrusted: bool = False,
) -> Agglomeration:
    """`agglomerate` with the parameters as the service's job dict ({model, mode, k, ..., options:
    {...}}, see models.params): what the CLI and models.api.run_job call."""
    import time

    p = validate_params(params)  # before the mesh is read: bad keywords fail at once
    o = p["options"]
    t0 = time.perf_counter()
    if o.get("fill"):  # a closed surface (STL, OBJ, PLY, OFF) filled with tetrahedra first
        from models.mesh.fill import DEFAULT_MAX_CELLS, fill_mesh

        if progress is not None:
            progress(0.0, "fill")
        mesh = fill_mesh(
            source,
            remesh=o["fill_remesh"],
            size=o["fill_size"],
            size_abs=o["fill_size_abs"],
            max_cells=o["fill_max_cells"] or DEFAULT_MAX_CELLS,
            seed=o["seed"],
            progress=None if progress is None else (lambda frac, stage: progress(0.2 * frac, "fill")),
        )
    else:
        mesh = read_mesh(
            source,
            points=points,
            cells=cells,
            tags=tags,
            physical_tag=o["physical_tag"],
            weld=o["weld"],
            untrusted=untrusted,
        )
    t_read = time.perf_counter() - t0
    from models.mesh.dropped import left_out_info

    p = validate_params(
        params,
        {
            "cells": mesh.n_cells,
            "cells_left_out": left_out_info(mesh.meta),
            "physical_groups": mesh.physical_groups(),
            "dim": mesh.dim,
            "filled": bool(o.get("fill")),
        },
    )
    p = _subset_as_read(mesh, p)
    o = p["options"]
    if p["model"] == "rl-partitioner" and p["mode"] != "multilevel" and mesh.n_cells > SLOW_CELLS:
        (warn or _stderr)(
            f"rl-partitioner on {mesh.n_cells} cells outside mode multilevel is slow (about 2 minutes "
            "for 14,000 cells); mode multilevel runs it on coarse graphs only"
        )
    from models import pipeline

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
        model_options={"method": o["method"]} if p["model"] == "metis" else None,
        compute_metrics=metrics,
        progress=progress,
        size_measure=o["size_measure"],
        refiner=p["refiner"],
        threshold=o["threshold"],
        record_levels=o["hierarchy"] and o["ratio"] is None and o["finest"] is None and not o["boxfit"],
        keep_groups=o["keep_groups"],
        allow_extra=o["allow_extra"],
    )
    res.timings = {"fill" if o.get("fill") else "read": t_read, **res.timings}
    if o.get("fill"):
        res.mesh.meta.setdefault("fill", mesh.meta.get("fill"))
    return Agglomeration(res, p)


class Agglomeration:
    """The result of `agglomerate`: labels (fine cell -> element), elements (the polytopes as
    arrays), metrics, and writers."""

    def __init__(self, result: Result, params: dict):
        self.result = result
        self.params = params

    def __repr__(self) -> str:
        return f"<Agglomeration: {self.n_elements} elements from {self.mesh.n_cells} cells ({self.params['model']})>"

    @property
    def mesh(self) -> Mesh:
        """The fine mesh, as read (oriented, validated)."""
        return self.result.mesh

    @property
    def labels(self):
        """(cells,) int64: the element of every fine cell, 0..n_elements-1."""
        return self.result.agglomeration.labels

    @property
    def input_labels(self):
        """One label per cell given (a file's cells, or cells= in their order): -1 for the few bad
        cells the read left out and said (a missing point, no area, a repeat); `labels` holds the
        cells read, in the order of `mesh`."""
        from models.pipeline import input_labels

        return input_labels(self.mesh, self.labels)

    @property
    def n_elements(self) -> int:
        return int(self.result.poly.n_elements)

    @property
    def elements(self) -> PolyMesh:
        """The polygons / polyhedra as arrays (models.mesh.container.PolyMesh): points, and per
        element a CSR of loops (2D: its boundary loop, counter-clockwise) or faces (3D: outward)."""
        return self.result.poly

    def polygon(self, e: int):
        """2D: the point ids of element e's boundary loop, counter-clockwise."""
        import numpy as np

        p = self.result.poly
        if p.dim != 2:
            raise ParameterError("polygon() is for 2D results; 3D elements are polyhedra (see .elements)")
        if isinstance(e, bool) or not isinstance(e, int | np.integer) or not 0 <= e < self.n_elements:
            raise ParameterError(f"polygon(e): e is an element number, 0 to {self.n_elements - 1}, got {e}")
        lo = p.loop_offsets[p.elem_offsets[e]]
        return p.loop_nodes[lo : p.loop_offsets[p.elem_offsets[e] + 1]]

    @property
    def metrics(self) -> dict:
        """The metrics report (per element, summary, partition), computed on first use."""
        if self.result.metrics is None:
            from models.pipeline import element_metrics

            self.result.metrics = element_metrics(self.result)
        return self.result.metrics

    @property
    def timings(self) -> dict:
        return dict(self.result.timings)

    def summary(self) -> dict:
        """{elements, requested, parts_split, fragments_absorbed, recount, holes_split, cells, dim, timings}."""
        return self.result.summary()

    def write(self, path: str | os.PathLike, kind: str | None = None, boundary_tag: int | None = None) -> str:
        """Write by suffix: .vtu (the polytopes with per-element metrics), .json (the metrics report),
        .mat (lymph structs, 2D), .ucd / .inp (deal.II: fine cells, material id = element), .png
        (a picture). kind="labels" writes the labels as a JSON list, kind="lymph" a .json lymph file."""
        import numpy as np

        from models import pipeline

        path = _out_path(path, "a file")
        ext = os.path.splitext(path)[1].lower()
        kind = kind or {
            ".vtu": "mesh",
            ".json": "metrics",
            ".mat": "lymph",
            ".ucd": "ucd",
            ".inp": "ucd",
            ".png": "plot",
        }.get(ext)
        if kind is None:
            raise ParameterError(
                f"cannot tell what to write to {path}: use .vtu, .json, .mat, .ucd, .inp or .png"
            )
        if os.path.isdir(path):
            raise ParameterError(f"cannot write to {path}: it is a folder")
        tag = self.params["options"]["boundary_tag"] if boundary_tag is None else boundary_tag
        if isinstance(tag, bool) or not isinstance(tag, int | np.integer) or not 0 <= tag < 2**31:
            raise ParameterError(f"boundary_tag must be a whole number from 0 to 2^31 - 1, got {tag}")
        if kind == "ucd":
            from models.export.ucd import write_ucd

            write_ucd(
                path,
                self.mesh,
                material=self.labels,
                comment=f"magnet: {self.n_elements} agglomerated elements; material id = element (0-based)",
            )
            return path
        if kind == "metrics":
            self.metrics  # noqa: B018  (computed here, not timed as "write")
            extra = {"params": self.params}
            from models.params import MODEL_VERSION

            extra["model_version"] = MODEL_VERSION
            pipeline.write_outputs(self.result, metrics=path, extra=extra, boundary_tag=tag)
            return path
        if kind == "mesh" and self.result.metrics is None:
            self.metrics  # noqa: B018  (the VTU carries the per-element metrics)
        where = {"mesh": "vtu", "labels": "labels", "lymph": "lymph", "plot": "plot"}
        if kind not in where:
            raise ParameterError(
                f"kind must be one of {', '.join(sorted([*where, 'metrics', 'ucd']))}, got {kind!r}"
            )
        pipeline.write_outputs(self.result, **{where[kind]: path}, boundary_tag=tag)
        return path

    def write_hierarchy(self, folder: str | os.PathLike, lymph: bool = False) -> dict:
        """The nested levels of a recursive run (agglomerate(..., hierarchy=True)) into `folder`;
        returns the hierarchy.json index."""
        from models import pipeline

        return pipeline.write_hierarchy(
            self.result,
            os.fspath(folder),
            lymph=lymph,
            boundary_tag=self.params["options"]["boundary_tag"],
        )

    def to_meshio(self) -> meshio.Mesh:
        """The polytopes as a meshio.Mesh (polygon / polyhedron blocks) with the per-element metrics
        as cell data (when computed)."""
        import tempfile

        import meshio

        from models.export.vtu import write_vtu

        cell_data = {}
        if self.result.metrics is not None:
            import numpy as np

            cell_data = {
                n: np.asarray(v, dtype=np.float64) for n, v in self.result.metrics["per_element"].items()
            }
        with tempfile.TemporaryDirectory(prefix="magnet-") as tmp:
            path = os.path.join(tmp, "elements.vtu")
            write_vtu(path, self.result.poly, cell_data)
            return meshio.read(path)

    def to_pyvista(self):
        """The polytopes as a pyvista.UnstructuredGrid (needs pyvista)."""
        try:
            import pyvista
        except ImportError:
            raise ParameterError(
                "to_pyvista() needs pyvista (pip install pyvista); to_meshio() does not"
            ) from None
        return pyvista.from_meshio(self.to_meshio())


def build_hierarchy(
    source=None,
    *,
    points=None,
    cells=None,
    tags=None,
    model: str = "rtree",
    ratio: float | None = None,
    coarsest: int = 10,
    groups: bool = False,
    seed: int = 0,
    physical_tag: str | None = None,
    weld: float | None = None,
    kappa=None,
    finest: str | None = None,
    boxfit: bool = False,
    keep_rings: bool = False,
) -> Hierarchy:
    """Nested levels for multigrid (as `magnet hierarchy`): about `ratio` times fewer elements per
    level down to at most `coarsest`; every element connected, every level nested in the next finer.
    ratio None: a schedule by dimension (2D n/5 then 8x fewer per level, 3D n/8 then 16x).
    kappa: "kx,ky[,kz]" or a sequence, the diagonal diffusion tensor the levels are cut for (rtree).
    finest: how the finest level is made (rtree; None: "aggregation" with the default schedule and no
    kappa, else "cuts"): "aggregation" (pyamg's standard aggregation of the cells' graph, rtree cuts
    above: pyamg's iterations, ragged coarse boxes), "cuts" (rtree cuts of the cells at every level:
    box-shaped elements, more iterations), "quality" (pairwise quality-controlled aggregates: fewer
    iterations, higher operator complexity), "nested" (pyamg's aggregation inside the cells' cuts:
    the cuts' boxes above the finest level). boxfit: then move boundary cells towards tighter boxes
    (models.hierarchy.boxfit; any model). keep_rings: 3D elements with a handle (rings around a
    tunnel or a neighbour) are kept, not cut (faster; info["notes"] counts them)."""
    import numpy as np

    if isinstance(coarsest, float | np.floating) and float(coarsest).is_integer():
        coarsest = int(coarsest)  # (4.0, as k = 8.0 is taken)
    if isinstance(coarsest, bool) or not isinstance(coarsest, int | np.integer):
        raise ParameterError(f"coarsest must be a whole number of elements, got {coarsest!r}")
    for name, value in (("groups", groups), ("keep_rings", keep_rings), ("boxfit", boxfit)):
        if not isinstance(value, bool | np.bool_):  # ("false" or an array is no switch)
            raise ParameterError(f"{name} must be true or false, got {shown(value)}")
    opts = {"seed": seed, "hierarchy": True, "coarsest": int(coarsest)}
    if ratio is not None:
        opts["ratio"] = ratio
    if finest is not None:
        opts["finest"] = finest
    if boxfit:
        opts["boxfit"] = bool(boxfit)
    try:
        params = validate_params({"model": model, "nref": 1, "options": opts})
    except ParameterError as exc:  # (the service's options.ratio is this function's ratio)
        raise _own_words(exc) from None
    from models.hierarchy.nested import build_hierarchy as build
    from models.pipeline import prepare

    mesh = read_mesh(source, points=points, cells=cells, tags=tags, physical_tag=physical_tag, weld=weld)
    graph, data = prepare(mesh)
    o = params["options"]
    if kappa is not None:
        from models.hierarchy.multigrid import parse_kappa

        try:
            text = kappa if isinstance(kappa, str) else ",".join(str(float(v)) for v in kappa)
        except (TypeError, ValueError):
            raise ParameterError(
                'kappa must be "kx,ky[,kz]" or a sequence of 2 or 3 positive numbers (a diagonal tensor)'
            ) from None
        kappa = parse_kappa(text, mesh.dim)
    levels, info = build(
        mesh,
        data,
        model=params["model"],
        ratio=o["ratio"],
        coarsest=o["coarsest"],
        seed=o["seed"],
        groups=groups,
        kappa=kappa,
        model_options={k: o[k] for k in ("finest", "boxfit") if o[k]}
        | ({"rings": False} if keep_rings else {}),
    )
    return Hierarchy(mesh, graph, data, levels, info)


class Hierarchy:
    """Nested levels, coarsest first: `levels[i]` is the (cells,) labels of level i."""

    def __init__(self, mesh, graph, data, levels, info):
        self.mesh, self.graph, self.data, self.levels = mesh, graph, data, levels
        self.merged = info.pop("merged")
        self.info = info
        self.removed: list[str] = []  # (write: an earlier hierarchy's level files it removed)

    def __repr__(self) -> str:
        sizes = " > ".join(str(int(lv.max()) + 1) for lv in self.levels)
        return f"<Hierarchy: {len(self.levels)} levels ({sizes} elements) from {self.mesh.n_cells} cells>"

    def write(self, folder: str | os.PathLike, metrics: bool = False, lymph: bool = False) -> dict:
        """level_L.vtu, .labels.json, .parent.json, .metrics.json, aggregation operators and
        hierarchy.json into `folder`; returns the hierarchy.json index. Level files an earlier
        hierarchy left there that this one does not write are removed (their names: `removed`;
        nothing else in the folder is touched). In 3D the elements are
        written numbered by their vertex count (the order meshio reads back): `levels` takes that
        numbering too (the same partition)."""
        import numpy as np

        from models.hierarchy.nested import write_hierarchy
        from models.mesh.boundary import fine_boundary, has_groups

        for name, value in (("metrics", metrics), ("lymph", lymph)):
            if not isinstance(value, bool | np.bool_):
                raise ParameterError(f"{name} must be true or false, got {shown(value)}")
        m, g = self.mesh, self.graph
        if lymph and m.dim != 2:  # (before anything is written: --lymph was asked of a 3D mesh)
            raise ParameterError("lymph's mesh structs (--lymph) are for 2D meshes only; this mesh is 3D")
        boundary = fine_boundary(m, g.faces, g.partner) if has_groups(m) else None
        keys = (
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
        folder = _out_path(folder, "a folder")
        if os.path.exists(folder) and not os.path.isdir(folder):
            raise ParameterError(f"cannot write the hierarchy to {folder}: it is a file, not a folder")
        written: dict = {}
        index = write_hierarchy(
            folder,
            m,
            self.data,
            self.levels,
            metrics=metrics,
            lymph=lymph,
            boundary=boundary,
            merged=self.merged,
            extra={key: self.info[key] for key in keys if key in self.info},
            written=written,
        )
        # the levels take the numbering written (3D: elements by vertex count, as meshio reads them
        # back), so that levels[L] and level_L.vtu / .labels.json / the operators name the same elements
        self.levels, self.merged = written["levels"], written["merged"]
        # the level files of an earlier, deeper hierarchy in the folder, removed (not nested with these)
        self.removed = written.get("removed", [])
        return index


def count_note(summary: dict, hierarchy: bool) -> str | None:
    """Why a recursive run kept with its levels (hierarchy) has other than the 2^nref elements asked
    for, or None: the last bisection's parts stay as they are there (a nested level), each piece of
    a part in pieces an element; without the levels the count is exact."""
    n, asked = summary["elements"], summary["requested"]
    if not hierarchy or summary.get("asked") != "2^nref" or n == asked:
        return None
    return (
        f"{n:,} elements, not 2^nref = {asked:,}: with hierarchy=True, the last bisection's parts "
        f"stay as they are ({summary.get('parts_split', 0):,} were in pieces, each piece an element); "
        "without it the count is exact"
    )


def _own_words(exc: ParameterError) -> ParameterError:
    """The refusal with this module's keyword names (ratio, seed; allow_extra=True) for the service's
    options.ratio; the service's words kept as `options_words`, which the CLI turns into its flags
    (--ratio), and `field` as a keyword's name."""
    said = str(exc).replace("options.allow_extra)", "allow_extra=True)")
    out = ParameterError(said.replace("options.", ""))
    out.options_words = str(exc)
    field = getattr(exc, "field", None)
    out.field = field.removeprefix("options.") if isinstance(field, str) else field
    return out


def _out_path(path, what: str) -> str:
    """An output path as a str (bytes decoded), refused in one sentence where it is none or its
    folder does not exist."""
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if not isinstance(path, str | os.PathLike):
        raise ParameterError(f"give the path of {what} to write to, got a {type(path).__name__}")
    path = os.fspath(path)
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise ParameterError(f"cannot write to {path}: folder {parent} does not exist")
    return path


def _stderr(line: str) -> None:
    import sys

    print(f"magnet: warning: {line}", file=sys.stderr)


def _meshio_from_arrays(points, cells, tags) -> meshio.Mesh:
    """points= / cells= / tags= as a meshio.Mesh, each checked: real coordinates in 2 or 3 columns;
    cells a list of (meshio cell type, (n, nodes) whole-number ids) pairs, the width the type has;
    tags one whole number per cell of each block. What does not fit is refused in one sentence."""
    import meshio
    import numpy as np
    from meshio._common import num_nodes_per_cell

    if isinstance(cells, dict):
        cells = list(cells.items())
    try:
        blocks = [(name, np.asarray(conn)) for name, conn in cells]
    except (TypeError, ValueError):
        raise ParameterError(
            "cells must be a list of (cell type, connectivity) pairs, e.g. [('triangle', tri)]"
        ) from None
    for name, conn in blocks:
        if not isinstance(name, str) or (name not in num_nodes_per_cell and not name.startswith("polygon")):
            raise ParameterError(
                f"unknown cell type '{name}' in cells=: use meshio's names (triangle, quad, polygon, "
                "tetra, hexahedron, wedge, pyramid, triangle6, tetra10, ...)"
            )
        if conn.dtype.kind not in "iuf" or conn.ndim != 2:
            raise ParameterError(
                f"the {name} cells must be an (n, nodes) array of point ids, got "
                + (
                    f"a {conn.ndim}-dimensional array"
                    if conn.dtype.kind in "iuf"
                    else "other values than numbers"
                )
            )
        if not _whole(conn):
            raise ParameterError(f"the {name} cells' point ids must be whole numbers")
        width = num_nodes_per_cell.get(name)
        if width is not None and conn.shape[1] != width:
            raise ParameterError(f"a {name} has {width} nodes, but its cells here have {conn.shape[1]}")
    blocks = [(name, conn.astype(np.int64)) for name, conn in blocks]
    try:
        pts = np.asarray(points)
    except ValueError:
        raise ParameterError("points must be an (n, 2) or (n, 3) array: its rows differ in length") from None
    if pts.dtype.kind not in "iuf":
        raise ParameterError(
            "points must be real numbers, an (n, 2) or (n, 3) array"
            + (" (complex given)" if pts.dtype.kind == "c" else "")
        )
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise ParameterError(f"points must be an (n, 2) or (n, 3) array, got shape {tuple(pts.shape)}")
    cell_data = {}
    if tags is not None:
        if isinstance(tags, np.ndarray) and len(blocks) == 1 and tags.ndim == 1:
            tags = [tags]  # (one block: its tags as one array)
        if not isinstance(tags, list | tuple) or len(tags) != len(blocks):
            raise ParameterError(f"tags must hold one array per cell block ({len(blocks)})")
        out = []
        for (name, conn), t in zip(blocks, tags, strict=True):
            t = np.asarray(t).reshape(-1)
            if t.size != len(conn):
                raise ParameterError(
                    f"tags must hold one number per {name} cell ({len(conn):,}), got {t.size:,}"
                )
            if t.dtype.kind not in "iuf" or not _whole(t):
                raise ParameterError("tags must be whole numbers (a physical group per cell)")
            out.append(t.astype(np.int64))
        cell_data["gmsh:physical"] = out
    try:
        return meshio.Mesh(pts.astype(np.float64), blocks, cell_data=cell_data)
    except (TypeError, ValueError, KeyError):
        raise MeshError("points / cells do not form a mesh (their shapes do not agree)") from None


def _whole(a) -> bool:
    """An integer array, or a float one holding whole finite numbers only."""
    import numpy as np

    return a.dtype.kind != "f" or not a.size or bool(np.all(np.isfinite(a) & (a == np.round(a))))


def _meshio_from_grid(grid) -> meshio.Mesh:
    """A VTK (vtkUnstructuredGrid) or pyvista UnstructuredGrid as meshio blocks: one block per run
    of cells of one type and size, so the cells keep their order (labels follow the grid's cells)."""
    import meshio
    import numpy as np
    from meshio._vtk_common import vtk_to_meshio_type

    if hasattr(grid, "GetCellTypesArray"):  # plain VTK
        from vtkmodules.util.numpy_support import vtk_to_numpy

        if grid.GetPoints() is None:
            raise MeshError("the VTK grid has no points")
        points = vtk_to_numpy(grid.GetPoints().GetData())
        ca = grid.GetCells()
        offsets = vtk_to_numpy(ca.GetOffsetsArray()).astype(np.int64)
        conn = vtk_to_numpy(ca.GetConnectivityArray()).astype(np.int64)
        try:  # VTK >= 9.6: GetCellTypes() is the array (GetCellTypesArray is deprecated)
            types_array = grid.GetCellTypes()
        except TypeError:
            types_array = grid.GetCellTypesArray()
        types = vtk_to_numpy(types_array).astype(np.int64)
        cd = grid.GetCellData()
        data = {
            cd.GetArrayName(i): vtk_to_numpy(cd.GetArray(i))
            for i in range(cd.GetNumberOfArrays())
            if cd.GetArray(i) is not None
        }
    else:  # pyvista
        points = np.asarray(grid.points)
        offsets = np.asarray(grid.offsets, dtype=np.int64)
        conn = np.asarray(grid.cell_connectivity, dtype=np.int64)
        types = np.asarray(grid.celltypes, dtype=np.int64)
        data = {name: np.asarray(grid.cell_data[name]) for name in grid.cell_data.keys()}
    if types.size == 0:
        raise MeshError("the grid has no cells")
    if np.any(types == 42):
        raise MeshError("polyhedral cells in a VTK grid: write the grid to .vtu and pass the path")
    sizes = np.diff(offsets)
    cut = np.flatnonzero((types[1:] != types[:-1]) | (sizes[1:] != sizes[:-1])) + 1
    starts, ends = np.r_[0, cut], np.r_[cut, types.size]
    blocks, cell_data = [], {name: [] for name in data}
    for s, e in zip(starts, ends, strict=True):  # one per run of cells of one type (not per cell)
        t = int(types[s])
        if t not in vtk_to_meshio_type:
            raise MeshError(f"unsupported VTK cell type {t} in the grid")
        blocks.append((vtk_to_meshio_type[t], conn[offsets[s] : offsets[e]].reshape(e - s, int(sizes[s]))))
        for name, arr in data.items():
            cell_data[name].append(arr[s:e])
    return meshio.Mesh(points, blocks, cell_data={n: v for n, v in cell_data.items() if n})
