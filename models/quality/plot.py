"""Pictures of an agglomeration and of its quality metrics (matplotlib, no screen needed).

Figures are built with `matplotlib.figure.Figure` on the Agg canvas, never through pyplot, so
nothing global (backend, current figure) changes and the functions are safe in a worker process.

- plot_agglomeration: 2D elements as one PolyCollection, neighbours in different colours (a
  randomized greedy colouring of the element adjacency, vectorized in rounds), element edges black,
  optionally the fine mesh in thin grey. 3D: an exploded view of the elements' boundary faces.
- plot_metric_boxplots: one subplot per metric, one box per method (as in the MAGNET paper).
- metrics_table: plain-text table of the mean metrics per method.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PathCollection, PolyCollection
from matplotlib.colors import to_rgba_array
from matplotlib.figure import Figure
from matplotlib.path import Path as MplPath

from models.errors import ParameterError
from models.mesh.container import Mesh, PolyMesh
from models.mesh.dual import sorted_unique

# Qualitative palette (matplotlib tab20, light and dark tones interleaved) used by the colouring.
_PALETTE = to_rgba_array(
    [
        "#aec7e8",
        "#ffbb78",
        "#98df8a",
        "#ff9896",
        "#c5b0d5",
        "#c49c94",
        "#f7b6d2",
        "#dbdb8d",
        "#9edae5",
        "#1f77b4",
        "#ff7f0e",
        "#2ca02c",
        "#d62728",
        "#9467bd",
        "#8c564b",
        "#e377c2",
        "#bcbd22",
        "#17becf",
    ]
)

METRIC_SHORT = {
    "circle_ratio": "CR",
    "area_perimeter_ratio": "APR",
    "sphericity": "Sph",
    "uniformity_factor": "UF",
    "volume_difference": "VD",
    "heterogeneity_preservation": "HP",
    "box_ratio": "BR",
    "box_circle_ratio": "CRbox",
}


def _new_figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path, dpi: int, tight: bool = True) -> str:
    """Save as PNG; `tight` crops the margins at the cost of a second draw pass."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight" if tight else None, format="png")
    return str(path)


# ---------------------------------------------------------------------------------------------
# colouring


def _padded_index(offs: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """(F, kmax) positions of every face's nodes, short faces padded with their last node."""
    k = int(sizes.max()) if sizes.size else 1
    return offs[:-1, None] + np.minimum(np.arange(k)[None, :], sizes[:, None] - 1)


def element_adjacency(poly: PolyMesh) -> np.ndarray:
    """(A, 2) pairs of elements that share a boundary edge (2D) or a boundary face (3D)."""
    offs = np.asarray(poly.loop_offsets, dtype=np.int64)
    nodes = np.asarray(poly.loop_nodes, dtype=np.int64)
    loop_elem = np.repeat(np.arange(poly.n_elements, dtype=np.int64), np.diff(poly.elem_offsets))
    sizes = np.diff(offs)
    if nodes.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    n_pts = np.int64(max(int(nodes.max()) + 1, 1))
    if poly.dim == 2:
        nxt = np.arange(nodes.shape[0], dtype=np.int64) + 1
        nxt[offs[1:] - 1] = offs[:-1]
        a, b = nodes, nodes[nxt]
        key = np.minimum(a, b) * n_pts + np.maximum(a, b)
        owner = np.repeat(loop_elem, sizes)
    else:
        # A face is identified by its three smallest node ids (enough for conforming meshes).
        if np.any(sizes < 3):
            raise ParameterError("a 3D face has fewer than 3 nodes")
        first3 = np.sort(nodes[_padded_index(offs, sizes)], axis=1)[:, :3]
        key = (first3[:, 0] * n_pts + first3[:, 1]) * n_pts + first3[:, 2]
        owner = loop_elem
    order = np.argsort(key, kind="stable")
    ks = key[order]
    same = np.flatnonzero(ks[1:] == ks[:-1])
    pairs = np.column_stack([owner[order[same]], owner[order[same + 1]]])
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    if pairs.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = np.sort(pairs, axis=1)
    return np.unique(pairs, axis=0)


def color_elements(n: int, pairs: np.ndarray, n_colors: int = len(_PALETTE), seed: int = 0) -> np.ndarray:
    """Colour ids (n,) with different colours across every pair, preferring ids < n_colors.

    Jones-Plassmann rounds: an uncoloured node whose random priority beats all its uncoloured
    neighbours takes a random colour (among the first n_colors) unused by its coloured
    neighbours; ids >= n_colors only when all of those are taken. Vectorized per round.
    """
    rng = np.random.default_rng(seed)
    colors = np.full(n, -1, dtype=np.int64)
    if n == 0:
        return colors
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    u = np.concatenate([pairs[:, 0], pairs[:, 1]])
    w = np.concatenate([pairs[:, 1], pairs[:, 0]])
    prio = rng.permutation(n)
    max_deg = int(np.bincount(u, minlength=n).max()) if u.size else 0
    width = max(n_colors, max_deg + 1)
    pref = np.where(np.arange(width) < n_colors, 0.0, -1.0 - np.arange(width))
    while True:
        todo = colors < 0
        if not todo.any():
            break
        both = todo[u] & todo[w]
        blocked = np.zeros(n, dtype=bool)
        blocked[u[both & (prio[w] > prio[u])]] = True
        sel = np.flatnonzero(todo & ~blocked)
        slot = np.full(n, -1, dtype=np.int64)
        slot[sel] = np.arange(sel.size)
        used = np.zeros((sel.size, width), dtype=bool)
        hit = (slot[u] >= 0) & (colors[w] >= 0)
        used[slot[u[hit]], colors[w[hit]]] = True
        score = np.where(used, -np.inf, pref[None, :] + rng.random((sel.size, width)) * (pref[None, :] == 0))
        colors[sel] = np.argmax(score, axis=1)
    return colors


def _element_colors(poly: PolyMesh, seed: int = 0) -> np.ndarray:
    ids = color_elements(poly.n_elements, element_adjacency(poly), seed=seed)
    return _PALETTE[ids % len(_PALETTE)]


# ---------------------------------------------------------------------------------------------
# agglomeration pictures


def _fine_edges_2d(mesh: Mesh) -> np.ndarray:
    """(S, 2, 2) unique edges of a 2D fine mesh."""
    offs = np.asarray(mesh.offsets, dtype=np.int64)
    conn = np.asarray(mesh.connectivity, dtype=np.int64)
    nxt = np.arange(conn.shape[0], dtype=np.int64) + 1
    nxt[offs[1:] - 1] = offs[:-1]
    a, b = conn, conn[nxt]
    key = sorted_unique(np.minimum(a, b) * np.int64(mesh.n_points) + np.maximum(a, b))
    a, b = np.divmod(key, np.int64(mesh.n_points))
    pts = np.asarray(mesh.points, dtype=np.float64)[:, :2]
    return np.stack([pts[a], pts[b]], axis=1)


def _plot_2d(poly: PolyMesh, ax, fine_mesh: Mesh | None, colors: np.ndarray) -> None:
    pts = np.asarray(poly.points, dtype=np.float64)[:, :2]
    offs = np.asarray(poly.loop_offsets, dtype=np.int64)
    xy = pts[np.asarray(poly.loop_nodes, dtype=np.int64)]
    loops = np.split(xy, offs[1:-1])
    n_loops = np.diff(poly.elem_offsets)
    lw = float(np.clip(2.0 / math.sqrt(max(poly.n_elements, 1)) * 4, 0.2, 1.2))
    if np.all(n_loops == 1):
        faces = PolyCollection(loops, facecolors=colors, edgecolors="none", zorder=1)
        edges = PolyCollection(loops, facecolors="none", edgecolors="k", linewidths=lw, zorder=3)
    else:  # elements with holes: compound paths (holes are clockwise)
        paths = []
        eo = np.asarray(poly.elem_offsets, dtype=np.int64)
        for e in range(poly.n_elements):  # one compound path per element (only with holes)
            parts = loops[eo[e] : eo[e + 1]]
            verts = np.concatenate([np.vstack([p, p[:1]]) for p in parts])
            codes = np.concatenate(
                [np.r_[MplPath.MOVETO, np.full(len(p) - 1, MplPath.LINETO), MplPath.CLOSEPOLY] for p in parts]
            ).astype(MplPath.code_type)
            paths.append(MplPath(verts, codes))
        faces = PathCollection(paths, facecolors=colors, edgecolors="none", zorder=1)
        edges = PathCollection(paths, facecolors="none", edgecolors="k", linewidths=lw, zorder=3)
    ax.add_collection(faces)
    if fine_mesh is not None:
        if fine_mesh.dim != 2:
            raise ParameterError("fine_mesh must be the 2D fine mesh of this agglomeration")
        ax.add_collection(LineCollection(_fine_edges_2d(fine_mesh), colors="0.45", linewidths=0.15, zorder=2))
    ax.add_collection(edges)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    pad = 0.02 * float(np.max(hi - lo) or 1.0)
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_axis_off()


def _plot_3d(poly: PolyMesh, ax, colors: np.ndarray, explode: float, max_faces: int) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    pts = np.asarray(poly.points, dtype=np.float64)
    offs = np.asarray(poly.loop_offsets, dtype=np.int64)
    sizes = np.diff(offs)
    ne = poly.n_elements
    face_elem = np.repeat(np.arange(ne, dtype=np.int64), np.diff(poly.elem_offsets))
    # Faces as a padded (F, kmax, 3) array: repeating the last vertex changes no polygon.
    xyz = pts[np.asarray(poly.loop_nodes, dtype=np.int64)[_padded_index(offs, sizes)]]
    fc = xyz.mean(axis=1)
    nf = np.maximum(np.bincount(face_elem, minlength=ne), 1)
    cen = (
        np.column_stack([np.bincount(face_elem, weights=fc[:, d], minlength=ne) for d in range(3)])
        / nf[:, None]
    )
    lo, hi = xyz.min(axis=(0, 1)), xyz.max(axis=(0, 1))
    shift = explode * (cen - 0.5 * (lo + hi))
    xyz += shift[face_elem][:, None, :]

    # Back-face culling towards the camera (faces are oriented outwards); Newell normals.
    elev, azim = 25.0, -55.0
    ax.view_init(elev=elev, azim=azim)
    ce, se = math.cos(math.radians(elev)), math.sin(math.radians(elev))
    ca, sa = math.cos(math.radians(azim)), math.sin(math.radians(azim))
    eye = np.array([ce * ca, ce * sa, se])
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    xn, yn, zn = (np.roll(c, -1, axis=1) for c in (x, y, z))
    toward = (eye[0] * (y * zn - z * yn) + eye[1] * (z * xn - x * zn) + eye[2] * (x * yn - y * xn)).sum(
        axis=1
    )
    visible = toward > 0
    del x, y, z, xn, yn, zn
    if not visible.any():
        visible[:] = True
    n_vis = np.bincount(face_elem[visible], minlength=ne)
    if n_vis.sum() > max_faces:  # keep the front layers: nearest elements of each screen patch
        right = np.array([-sa, ca, 0.0])
        pos = cen + shift
        uv = np.column_stack([pos @ right, pos @ np.cross(eye, right)])
        g = max(1, round(1.5 * ne ** (1.0 / 3.0)))
        span = np.maximum(np.ptp(uv, axis=0), 1e-300)
        cell = np.minimum((g * (uv - uv.min(axis=0)) / span).astype(np.int64), g - 1)
        patch = cell[:, 0] * g + cell[:, 1]
        depth = pos @ eye
        order = np.lexsort((-depth, patch))
        ps = patch[order]
        first = np.r_[0, np.flatnonzero(ps[1:] != ps[:-1]) + 1]
        rank = np.empty(ne, dtype=np.int64)
        rank[order] = np.arange(ps.size) - np.repeat(first, np.diff(np.r_[first, ps.size]))
        pick = np.lexsort((-depth, rank))
        fits = np.cumsum(n_vis[pick]) <= max_faces
        fits[0] = True
        drawn = np.zeros(ne, dtype=bool)
        drawn[pick[fits]] = True
        visible &= drawn[face_elem]
    faces = xyz[visible]
    if faces.shape[1] > 4:  # long padding would upset the shading normals: exact polygons
        faces = [f[:k] for f, k in zip(faces, sizes[visible], strict=True)]
    coll = Poly3DCollection(
        faces, facecolors=colors[face_elem[visible]], edgecolors=(0, 0, 0, 0.35), linewidths=0.1, shade=True
    )
    ax.add_collection3d(coll)
    ax.set_xlim(lo[0] + min(shift[:, 0].min(), 0), hi[0] + max(shift[:, 0].max(), 0))
    ax.set_ylim(lo[1] + min(shift[:, 1].min(), 0), hi[1] + max(shift[:, 1].max(), 0))
    ax.set_zlim(lo[2] + min(shift[:, 2].min(), 0), hi[2] + max(shift[:, 2].max(), 0))
    ext = np.array([np.diff(ax.get_xlim())[0], np.diff(ax.get_ylim())[0], np.diff(ax.get_zlim())[0]])
    ax.set_box_aspect(np.maximum(ext, 1e-12 * float(ext.max() or 1.0)))
    ax.set_axis_off()


def plot_agglomeration(
    poly: PolyMesh,
    path,
    fine_mesh: Mesh | None = None,
    title: str | None = None,
    dpi: int = 150,
    explode: float = 0.5,
    seed: int = 0,
    max_faces: int = 60_000,
) -> str:
    """Write a PNG of the agglomerated mesh and return its path.

    2D: filled elements (neighbours differ in colour), element edges black, and the fine mesh
    in thin grey when given. 3D: exploded view, every element moved away from the mesh centre
    by `explode` times (element centroid - mesh centre), only faces turned to the camera drawn;
    beyond `max_faces` such faces only the front layers are drawn (per screen patch, the elements
    nearest to the camera first), since matplotlib draws only some 25k polygons a second.
    """
    if poly.n_elements < 1:
        raise ParameterError("nothing to plot: the agglomeration has no element")
    colors = _element_colors(poly, seed=seed)
    if poly.dim == 2:
        pts = np.asarray(poly.points)
        ext = np.ptp(pts[np.asarray(poly.loop_nodes)], axis=0) if pts.size else np.ones(2)
        aspect = float(ext[1] / ext[0]) if ext[0] > 0 else 1.0
        width = 8.0
        fig = _new_figure(width, float(np.clip(width * aspect, 2.0, 14.0)))
        ax = fig.add_subplot(1, 1, 1)
        _plot_2d(poly, ax, fine_mesh, colors)
    elif poly.dim == 3:
        fig = _new_figure(8.0, 8.0)
        ax = fig.add_subplot(1, 1, 1, projection="3d")
        _plot_3d(poly, ax, colors, explode, max_faces)
    else:
        raise ParameterError(f"cannot plot a {poly.dim}D mesh")
    if title:
        ax.set_title(title)
    return _save(fig, path, dpi, tight=poly.dim == 2)


# ---------------------------------------------------------------------------------------------
# metrics


def _metric_names(results: dict[str, dict]) -> list[str]:
    names: list[str] = []
    for report in results.values():
        for k in report.get("per_element") or {}:
            if k not in names:
                names.append(k)
    return names


def _values(report: dict, metric: str) -> np.ndarray:
    vals = (report.get("per_element") or {}).get(metric)
    if vals is None:
        return np.zeros(0)
    v = np.array([np.nan if x is None else x for x in vals], dtype=np.float64)
    return v[np.isfinite(v)]


def plot_metric_boxplots(results: dict[str, dict], path, title: str | None = None, dpi: int = 150) -> str:
    """One subplot per metric with one box per method; returns the PNG path.

    results: method name -> metrics report ({"per_element": {metric: [values]}, ...}).
    """
    if not results:
        raise ParameterError("no results to plot")
    metrics = _metric_names(results)
    if not metrics:
        raise ParameterError("the reports have no per_element metrics")
    methods = list(results)
    ncols = min(len(metrics), 3)
    nrows = math.ceil(len(metrics) / ncols)
    box_w = max(2.8, 0.75 * len(methods) + 1.0)
    fig = _new_figure(box_w * ncols, 3.6 * nrows)
    cmap = _PALETTE[9:18]  # the saturated tones
    for i, metric in enumerate(metrics):
        ax = fig.add_subplot(nrows, ncols, i + 1)
        data = [_values(results[m], metric) for m in methods]
        pos = [p for p, d in enumerate(data, start=1) if d.size]
        bp = ax.boxplot(
            [d for d in data if d.size],
            positions=pos,
            widths=0.6,
            patch_artist=True,
            showfliers=True,
            flierprops={"markersize": 2},
        )
        for j, box in enumerate(bp["boxes"]):
            box.set_facecolor(cmap[(pos[j] - 1) % len(cmap)])
            box.set_alpha(0.8)
        for med in bp["medians"]:
            med.set_color("k")
        ax.set_xticks(range(1, len(methods) + 1))
        ax.set_xticklabels(
            methods, rotation=30 if len(methods) > 3 else 0, ha="right" if len(methods) > 3 else "center"
        )
        ax.set_xlim(0.4, len(methods) + 0.6)
        allv = np.concatenate(data) if any(d.size for d in data) else np.zeros(0)
        if allv.size and allv.min() >= 0 and allv.max() <= 1:
            ax.set_ylim(-0.03, 1.03)
        name = METRIC_SHORT.get(metric, metric)
        ax.set_title(name if name == metric else f"{name} ({metric.replace('_', ' ')})", fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path, dpi)


def _report_time(report: dict) -> float | None:
    t = report.get("time")
    if t is None:
        return None
    if isinstance(t, dict):
        vals = [float(x) for x in t.values() if isinstance(x, (int, float))]
        return float(sum(vals)) if vals else None
    return float(t)


def metrics_table(results: dict[str, dict]) -> str:
    """Plain-text table: one row per method; elements, mean of every metric, normalized cut
    (report["partition"]["normalized_cut"]) and time (report["time"], seconds) when present."""
    metrics = _metric_names(results)
    have_time = any(_report_time(r) is not None for r in results.values())
    header = ["method", "elements"] + [METRIC_SHORT.get(m, m) for m in metrics] + ["NC"]
    if have_time:
        header.append("time [s]")
    rows = []
    for name, report in results.items():
        per = report.get("per_element") or {}
        n = report.get("elements")
        if n is None and per:
            n = len(next(iter(per.values())))
        row = [str(name), "-" if n is None else str(int(n))]
        for m in metrics:
            v = _values(report, m)
            row.append(f"{v.mean():.3f}" if v.size else "-")
        nc = (report.get("partition") or {}).get("normalized_cut")
        row.append("-" if nc is None else f"{float(nc):.4f}")
        if have_time:
            t = _report_time(report)
            row.append("-" if t is None else f"{t:.2f}")
        rows.append(row)
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]

    def fmt(cells):
        return "  ".join(
            c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        )

    lines = [fmt(header), "  ".join("-" * w for w in widths)] + [fmt(r) for r in rows]
    return "\n".join(lines)
