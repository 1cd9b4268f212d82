"""docs/hierarchy-levels.png: three nested rtree levels of the brain mesh drawn one over the other
(coarse element boundaries thick, finer ones thinner; colours by the coarsest of the three).

    python scripts/hierarchy_picture.py [MESH] [-o docs/hierarchy-levels.png] [--ratio R]
    (docs/hierarchy-holes.png: a gmsh plate with four holes, bench/family_meshes.py plate_holes)
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default=os.path.join(ROOT, "tests", "data", "BrainCoronalNoHoles.vtu"))
    ap.add_argument("-o", "--output", default=os.path.join(ROOT, "docs", "hierarchy-levels.png"))
    ap.add_argument("--ratio", type=float, default=None, help="default: the schedule by dimension")
    a = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection, PolyCollection

    from models.hierarchy.nested import build_hierarchy
    from models.mesh.read import read_mesh
    from models.pipeline import prepare

    mesh = read_mesh(a.mesh)
    g, data = prepare(mesh)
    levels, _ = build_hierarchy(mesh, data, model="rtree", ratio=a.ratio, coarsest=10)
    three = levels[-3:]  # e.g. 29 > 225 > 1797 on the brain
    f = g.faces
    e = f.nodes.reshape(-1, 2)
    cell = f.cell
    other = np.where(g.partner >= 0, f.cell[np.maximum(g.partner, 0)], -1)
    pts = mesh.points[:, :2]
    fig, ax = plt.subplots(figsize=(9, 7.5))
    sizes_ = np.diff(mesh.offsets)
    if np.all(sizes_ == sizes_[0]):  # one cell type: one reshape
        tri = pts[mesh.connectivity.reshape(-1, int(sizes_[0]))]
    else:
        tri = np.split(pts[mesh.connectivity], mesh.offsets[1:-1])
    rng = np.random.default_rng(3)
    colours = plt.cm.tab20(rng.permutation(int(three[0].max()) + 1) % 20)
    ax.add_collection(PolyCollection(tri, facecolors=colours[three[0]], edgecolors="none", alpha=0.45))
    for lab, width, colour in zip(three[::-1], (0.4, 1.0, 2.4), ("0.45", "0.15", "black"), strict=True):
        cut = (other < 0) | (lab[cell] != lab[np.maximum(other, 0)])
        ax.add_collection(LineCollection(pts[e[cut]], linewidths=width, colors=colour))
    ax.autoscale()
    ax.set_aspect("equal")
    ax.axis("off")
    sizes = " > ".join(str(int(lv.max()) + 1) for lv in three)
    how = f"ratio {a.ratio:g}" if a.ratio else "default schedule"
    ax.set_title(f"three nested rtree levels ({how}): {sizes} elements, {mesh.n_cells} cells")
    fig.savefig(a.output, dpi=110, bbox_inches="tight")
    print(f"wrote {a.output} ({sizes})")


if __name__ == "__main__":
    main()
