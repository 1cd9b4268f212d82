"""Job parameters: the model cards and the one validation every way in shares (the Python API
models.agglomeration, the CLI, the worker through models.api.run_job, and the service).

Pure Python (no numpy): the service imports it. validate_params(params, mesh_info=None) -> the
normalized params dict, or ParameterError whose `field` names the parameter (e.g. "k",
"options.seed"; None when no single field is at fault).
"""

from __future__ import annotations

import math
import re

from models.errors import ParameterError, listed

MODEL_VERSION = "0.1.0"
MODES = ("kway", "nref", "target-size", "mult-factor", "segregated", "coarsen", "multilevel")
REFINERS = ("fm", "rl-refiner")
# how a hierarchy's finest level is made (models.hierarchy.nested.build_hierarchy, model_options["finest"])
FINEST_MODES = ("aggregation", "cuts", "quality", "nested")
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


def shown(value) -> str:
    """A value in a refusal: a scalar as written ('8', True, 2.5), anything else by its kind (an
    ndarray, a dict): never a repr of an array."""
    if isinstance(value, str | bool | int | float) or value is None:
        return repr(value)
    if type(value).__module__ == "numpy" and getattr(value, "ndim", 1) == 0:
        return repr(value.item())
    kind = {"ndarray": "array"}.get(type(value).__name__, type(value).__name__)
    return f"{'an' if kind[:1].lower() in 'aeiou' else 'a'} {kind}"


def list_models() -> list[dict]:
    return [dict(card, version=MODEL_VERSION) for card in MODEL_CARDS]


def _int(params: dict, name: str, lo: int | None = None, hi: int | None = None) -> int | None:
    v = params.get(name)
    if v is None:
        return None
    if isinstance(v, bool) or not (isinstance(v, int) or (isinstance(v, float) and v.is_integer())):
        raise ParameterError(f"{name} must be an integer, got {shown(v)}")
    v = int(v)
    if lo is not None and v < lo:
        raise ParameterError(f"{name} must be >= {lo}, got {v}")
    if hi is not None and v > hi:
        raise ParameterError(f"{name} must be <= {hi}, got {v}")
    return v


def _bool(opts: dict, name: str) -> bool:
    v = opts.get(name, False)
    if v in ("true", "false"):  # form fields arrive as strings
        v = v == "true"
    if not isinstance(v, bool):
        raise ParameterError(f"options.{name} must be true or false, got {shown(v)}")
    return v


def _float(params: dict, name: str, lo_open: float | None = None, hi: float | None = None) -> float | None:
    v = params.get(name)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ParameterError(f"{name} must be a number, got {shown(v)}")
    v = float(v)
    if not math.isfinite(v):
        raise ParameterError(f"{name} must be finite, got {v}")
    if lo_open is not None and v <= lo_open:
        raise ParameterError(f"{name} must be > {lo_open}, got {v}")
    if hi is not None and v > hi:
        raise ParameterError(f"{name} must be <= {hi}, got {v}")
    return v


SIZES = ("k", "nref", "target_size", "mult_factor")
# the size parameters each mode takes (mode inferred from the one given when no mode is named)
MODE_SIZES = {
    "kway": ("k",),
    "nref": ("nref",),
    "target-size": ("target_size",),
    "mult-factor": ("mult_factor",),
    "segregated": ("mult_factor",),
    "coarsen": SIZES,
    "multilevel": ("nref", "target_size", "mult_factor"),
}
_MODE_OF_SIZE = {"k": "kway", "nref": "nref", "target_size": "target-size", "mult_factor": "mult-factor"}
OPTION_NAMES = (
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
    "finest",
    "boxfit",
    "groups",
    "keep_rings",
    "kappa",
    "allow_extra",
    "keep_groups",
    "fill",
    "fill_remesh",
    "fill_size",
    "fill_size_abs",
    "fill_max_cells",
)  # the job's options (options.seed, ...)
_FIELDS = (*SIZES, "model", "mode", "subset", "refiner", "options")
_FIELD_RE = re.compile(r"^(options\.[a-z_]+|[a-z_]+)\b")


def _two_sizes(given: list[str], why: str = "") -> ParameterError:
    """The refusal of two size parameters, naming one of them as its field (the later in k, nref,
    target_size, mult_factor)."""
    two = ParameterError(f"give one size parameter, not {' and '.join(given)}{why}")
    two.field = given[1]
    return two


def infer_mode(params: dict) -> str:
    """The mode of a job that names none: the one its size parameter implies (k: kway, nref: nref,
    target_size: target-size, mult_factor: mult-factor; with a subset: coarsen); kway when none is
    given. Two size parameters are refused (ParameterError)."""
    given = [s for s in SIZES if params.get(s) is not None]
    if len(given) > 1:
        raise _two_sizes(given, ": each one chooses the number of elements its own way")
    if params.get("subset") is not None:
        return "coarsen"
    return _MODE_OF_SIZE[given[0]] if given else "kway"


def _plain(v):
    """Numpy scalars (np.int64(4), np.True_, a 0-d array) as the Python numbers they hold, all the
    way down a parameters dict: a caller computing k with numpy gets k, not "k must be an integer,
    got np.int64(4)"."""
    if isinstance(v, dict):
        return {key: _plain(x) for key, x in v.items()}
    if type(v).__module__ == "numpy" and hasattr(v, "item") and getattr(v, "ndim", 0) == 0:
        return v.item()
    return v


def validate_params(params: dict, mesh_info: dict | None = None) -> dict:
    """Check and normalize job parameters (before any work is queued). The ParameterError raised
    carries `field`: the parameter at fault (None when it is not one field)."""
    try:
        return _validate(_plain(params), mesh_info)
    except ParameterError as exc:
        if getattr(exc, "field", None) is None:
            m = _FIELD_RE.match(str(exc))
            name = m.group(1) if m else None
            if name in OPTION_NAMES:  # ("seed must be >= 0": the option options.seed)
                name = f"options.{name}"
            exc.field = name if name in _FIELDS or (name or "").startswith("options.") else None
        raise


def _validate(params: dict, mesh_info: dict | None) -> dict:
    if not isinstance(params, dict):
        raise ParameterError("parameters must be a JSON object")
    known = {"model", "mode", "k", "nref", "target_size", "mult_factor", "subset", "refiner", "options"}
    unknown = set(params) - known
    if unknown:
        raise ParameterError(f"unknown parameter(s): {', '.join(sorted(unknown))}")
    model = params.get("model", "metis")
    names = [c["name"] for c in MODEL_CARDS]
    if model not in names:
        raise ParameterError(f"model must be one of {', '.join(names)}, got {shown(model)}")
    mode = params.get("mode")
    if mode is None:
        mode = infer_mode(params)
    if mode not in MODES:
        raise ParameterError(f"mode must be one of {', '.join(MODES)}, got {shown(mode)}")
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
        raise ParameterError(f"refiner must be one of {', '.join(REFINERS)} or null, got {shown(refiner)}")
    if refiner == "rl-refiner" and (mode == "kway" or (mode == "coarsen" and k is not None)):
        raise ParameterError("refiner 'rl-refiner' refines bisections only; k-way mode takes refiner 'fm'")
    given = [s for s, v in zip(SIZES, (k, nref, target_size, mult_factor), strict=True) if v is not None]
    wrong = [s for s in given if s not in MODE_SIZES[mode]]
    if wrong:
        takes = " or ".join(MODE_SIZES[mode])
        raise ParameterError(f"{wrong[0]} does not go with mode {mode!r}, which takes {takes}")
    if len(given) > 1:
        raise _two_sizes(given)
    if mode == "multilevel" and all(v is None for v in (nref, target_size, mult_factor)):
        raise ParameterError("mode 'multilevel' needs one of nref, target_size, mult_factor")
    opts = params.get("options") or {}
    if not isinstance(opts, dict):
        raise ParameterError("options must be an object")
    known_opts = set(OPTION_NAMES)
    if set(opts) - known_opts:
        raise ParameterError(f"unknown option(s): {listed(sorted(set(opts) - known_opts))}")
    seed = _int(opts, "seed", lo=0, hi=2**31 - 1) or 0
    absorb = opts.get("absorb_fraction", 0.0)
    if isinstance(absorb, bool) or not isinstance(absorb, int | float) or not (0 <= absorb < 1):
        raise ParameterError(f"options.absorb_fraction must be a number in [0, 1), got {shown(absorb)}")
    hole_policy = opts.get("hole_policy", "split")
    if hole_policy not in ("split", "error"):
        raise ParameterError(f"options.hole_policy must be 'split' or 'error', got {shown(hole_policy)}")
    physical_tag = opts.get("physical_tag")
    if physical_tag is not None and (
        not isinstance(physical_tag, str) or not physical_tag or len(physical_tag) > 200
    ):
        raise ParameterError("options.physical_tag must be a non-empty string")
    boundary_tag = _int(opts, "boundary_tag", lo=0, hi=2**31 - 1)
    boundary_tag = 1 if boundary_tag is None else boundary_tag
    threshold = _int(opts, "threshold", lo=2, hi=1_000_000)
    threshold = 200 if threshold is None else threshold
    hierarchy = _bool(opts, "hierarchy")
    ratio = _float(opts, "ratio")
    if ratio is not None and ratio < 2:
        raise ParameterError(f"options.ratio must be >= 2 (coarsening ratio per level), got {ratio}")
    coarsest = _int(opts, "coarsest", lo=1, hi=10**9)
    if (ratio is not None or coarsest is not None) and not hierarchy:
        raise ParameterError("options.ratio and options.coarsest go with options.hierarchy = true")
    finest = opts.get("finest")
    if finest is not None and finest not in FINEST_MODES:
        raise ParameterError(
            f"options.finest must be aggregation, cuts, quality or nested (the finest level of the "
            f"hierarchy), got {shown(finest)}"
        )
    boxfit = _bool(opts, "boxfit")
    if (finest is not None or boxfit) and not hierarchy:
        raise ParameterError("options.finest and options.boxfit go with options.hierarchy = true")
    groups = _bool(opts, "groups")
    keep_rings = _bool(opts, "keep_rings")
    kappa = opts.get("kappa")
    if kappa is not None and (
        not isinstance(kappa, list | tuple)
        or len(kappa) not in (2, 3)
        or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and 0 < v < float("inf") for v in kappa
        )
    ):
        raise ParameterError(
            f"options.kappa must be 2 or 3 positive numbers [kx, ky(, kz)] (a diagonal diffusion tensor), "
            f"got {shown(kappa)}"
        )
    own_levels = hierarchy and (ratio is not None or finest is not None or boxfit)
    if (groups or keep_rings) and not own_levels:
        raise ParameterError(
            "options.groups and options.keep_rings go with a hierarchy of its own (options.hierarchy = "
            "true with options.ratio, options.finest or options.boxfit, like `magnet hierarchy`)"
        )
    if kappa is not None and not (
        hierarchy and model == "rtree" and (finest == "cuts" or (finest is None and boxfit))
    ):
        raise ParameterError(
            "options.kappa: levels cut for a diffusion tensor are rtree's levels of their own from the "
            "cells (options.hierarchy = true with options.finest = 'cuts' or options.boxfit), as "
            "`magnet hierarchy --kappa`"
        )
    if finest not in (None, "cuts") and (model != "rtree" or ratio is not None):
        raise ParameterError(
            f"options.finest = {finest!r} (an aggregated finest level) needs model rtree and no "
            "options.ratio (finest 'cuts' goes with any model and ratio)"
        )
    own = ratio is not None or finest is not None or boxfit  # a hierarchy of its own
    if hierarchy and not own and (mode == "kway" or (mode == "coarsen" and k is not None)):
        raise ParameterError(
            "options.hierarchy needs a recursive mode (nref, target-size, mult-factor, segregated, "
            "coarsen or multilevel), not k-way, or options.ratio (a hierarchy of its own, like "
            "`magnet hierarchy`)"
        )
    allow_extra = _bool(opts, "allow_extra")
    keep_groups = opts.get("keep_groups")
    if keep_groups is not None and not isinstance(keep_groups, bool):
        raise ParameterError(
            f"options.keep_groups must be true, false or null (auto), got {shown(keep_groups)}"
        )
    if keep_groups is True and refiner is None:  # (it weighs the refiner's cuts: alone it did nothing)
        raise ParameterError(
            "options.keep_groups acts on a refiner's cuts: give a refiner (--refiner fm "
            "or rl-refiner); for elements that never cross a physical group use mode segregated"
        )
    method = opts.get("method", "kway")
    if method not in ("kway", "recursive"):
        raise ParameterError(f"options.method must be 'kway' or 'recursive', got {shown(method)}")
    weld = _float(opts, "weld")
    if weld is not None and weld < 0:
        raise ParameterError(f"options.weld must be >= 0 (a distance), got {weld}")
    fill = _bool(opts, "fill")
    fill_remesh = _bool(opts, "fill_remesh")
    fill_size = _float(opts, "fill_size", lo_open=0.0, hi=1.0)
    fill_size_abs = _float(opts, "fill_size_abs", lo_open=0.0)
    fill_max_cells = _int(opts, "fill_max_cells", lo=1)
    if fill_size is not None and fill_size_abs is not None:
        raise ParameterError("options.fill_size (relative) and options.fill_size_abs (absolute): give one")
    if not fill and (fill_remesh or fill_size is not None or fill_size_abs is not None or fill_max_cells):
        raise ParameterError(
            "options.fill_remesh, fill_size, fill_size_abs and fill_max_cells go with options.fill"
        )
    size_measure = opts.get("size_measure", "centroids")
    if size_measure not in ("centroids", "vertices"):
        raise ParameterError(
            f"options.size_measure must be 'centroids' or 'vertices', got {shown(size_measure)}"
        )

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

    if mesh_info is not None and mesh_info.get("surface") is not None and not fill:
        raise ParameterError(
            f"options.fill: the mesh is a closed surface of {mesh_info['surface']['triangles']:,} triangles; "
            "set options.fill = true to fill it with tetrahedra"
        )
    if mesh_info is not None and fill and mesh_info.get("surface") is None and not mesh_info.get("filled"):
        raise ParameterError(
            "options.fill is for a closed surface (STL, OBJ, PLY, OFF), not a volume or planar mesh"
        )
    if mesh_info is not None and not (fill and mesh_info.get("surface") is not None):  # cells known
        n = int(mesh_info["cells"])
        # a subset names the file's cells: where the read left a few bad ones out (cells_left_out,
        # file ids), it may name those (they are left out of it), and ids run to the file's count
        left_out = mesh_info.get("cells_left_out") or {}
        n_file = int(left_out.get("file_cells", n))
        n_work = n if subset is None else len(set(subset) - set(left_out.get("ids_all", ())))
        if subset is not None and max(subset) >= n_file:
            raise ParameterError(
                f"subset has unknown cell ids (the mesh has cells 0..{n_file - 1}), e.g. {max(subset)}"
            )
        if k is not None and k > n_work:
            raise ParameterError(f"k = {k} is larger than the number of cells to agglomerate ({n_work})")
        if nref is not None and 2**nref > n_work:
            raise ParameterError(f"nref = {nref} asks for 2^{nref} elements, more than the {n_work} cells")
        if hierarchy and coarsest is not None and coarsest >= n_work:  # (as `magnet hierarchy` says it)
            few = ParameterError(
                f"the mesh has {n_work:,} cell{'s' if n_work != 1 else ''}: nothing to coarsen with "
                f"options.coarsest = {coarsest}"
            )
            few.field = "options.coarsest"
            raise few
        if kappa is not None and mesh_info.get("dim") not in (None, len(kappa)):
            raise ParameterError(
                f"options.kappa has {len(kappa)} values but the mesh is {mesh_info['dim']}D: give one per axis"
            )
        if keep_rings and mesh_info.get("dim") == 2:
            raise ParameterError(
                "options.keep_rings is for 3D meshes, whose elements may go around a tunnel; a 2D "
                "element never encloses a hole"
            )
        if groups and not mesh_info.get("physical_groups"):
            raise ParameterError(
                "options.groups: levels that keep physical groups apart need a mesh with them"
            )
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
            "finest": finest,
            "boxfit": boxfit,
            "groups": groups,
            "keep_rings": keep_rings,
            "kappa": None if kappa is None else [float(v) for v in kappa],
            "allow_extra": allow_extra,
            "keep_groups": keep_groups,
            **(
                {
                    "fill": True,
                    "fill_remesh": fill_remesh,
                    "fill_size": fill_size,
                    "fill_size_abs": fill_size_abs,
                    "fill_max_cells": fill_max_cells,
                }
                if fill
                else {}
            ),
        },
    }
