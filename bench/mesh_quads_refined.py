"""The R3MG test mesh's kind: an unstructured gmsh quad mesh of about 90 cells of the unit square,
refined `levels` times by splitting every quad in four (90 x 4^5 = 92,160 quads at 5).

    python bench/mesh_quads_refined.py OUT.vtu [--levels 5] [--h 0.125]
"""

from __future__ import annotations

import argparse

import numpy as np


def refined_quads(levels: int = 5, h: float = 0.125, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(points (P, 2), quads (C, 4)) of the refined unstructured quad mesh (gmsh's Blossom recombination)."""
    import gmsh

    gmsh.initialize(["-nt", "1"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.RandomSeed", seed)
        gmsh.model.add("square")
        gmsh.model.occ.addRectangle(0, 0, 0, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.RecombineAll", 1)
        gmsh.option.setNumber("Mesh.Algorithm", 5)  # Delaunay, then Blossom recombination
        gmsh.model.mesh.generate(2)
        for _ in range(levels):
            gmsh.model.mesh.refine()  # every quad -> 4 quads
        tags, coords, _ = gmsh.model.mesh.getNodes()
        pts = np.asarray(coords).reshape(-1, 3)[:, :2]
        index = np.empty(int(tags.max()) + 1, dtype=np.int64)
        index[tags] = np.arange(tags.size)
        types, _, nodes = gmsh.model.mesh.getElements(2)
        quads = [np.asarray(n).reshape(-1, 4) for t, n in zip(types, nodes, strict=True) if t == 3]
        if len(quads) != 1 or len(types) != 1:
            raise RuntimeError("gmsh did not give a pure quad mesh")
        q = index[quads[0]]
    finally:
        gmsh.finalize()
    used = np.unique(q)
    remap = np.full(pts.shape[0], -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return pts[used], remap[q]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--levels", type=int, default=5)
    ap.add_argument("--h", type=float, default=0.125)
    a = ap.parse_args()
    import meshio

    p, q = refined_quads(a.levels, a.h)
    meshio.write(a.out, meshio.Mesh(np.column_stack([p, np.zeros(len(p))]), [("quad", q)]))
    print(f"{a.out}: {len(q)} quads ({len(q) // 4**a.levels} before refinement), {len(p)} points")


if __name__ == "__main__":
    main()
