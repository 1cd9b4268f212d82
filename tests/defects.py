"""The defect corpus: small meshes with the defects real-world meshes have, written as files.

`python tests/defects.py` (re)writes tests/data/defects/; tests/test_defects.py asserts what each
one does. Every generator is deterministic (no random state without a fixed seed).
"""

from __future__ import annotations

import os
import sys

import meshio
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from meshes import hexes, mixed_2d, quads, tets, triangles  # noqa: E402

DATA = os.path.join(HERE, "data")
OUT = os.path.join(DATA, "defects")
BRAIN = os.path.join(DATA, "BrainCoronalNoHoles.vtu")


def _signed_areas(p, t):
    a, b, c = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    return 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])


def folded_brain():
    """The brain slice with one thin interior triangle folded over: its vertex opposite its longest
    edge reflected across that edge. Returns (points, triangles, folded cell id)."""
    m = meshio.read(BRAIN)
    p = np.asarray(m.points, dtype=np.float64)
    t = np.asarray(m.cells_dict["triangle"], dtype=np.int64)
    q2, c = fold_one_triangle(p[:, :2], t)  # (the file is a valid, unfolded mesh)
    q = p.copy()
    q[:, :2] = q2
    return q, t, c


def write_folded_brain(path: str) -> int:
    q, t, c = folded_brain()
    meshio.write(path, meshio.Mesh(q, [("triangle", t)]), binary=False)
    return c


def _tet_volumes(p, t):
    a, b, c, d = (p[t[:, j]] for j in range(4))
    return np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a)) / 6.0


def folded_tet(n: int = 3):
    """A cube of tetrahedra with one interior vertex pushed through the opposite face of one of
    its tetrahedra, so that exactly that one is inside out. Returns (points, tets, folded id)."""
    p, t = tets(n)
    p = p.astype(np.float64)
    t = np.where((_tet_volumes(p, t) < 0)[:, None], t[:, [0, 2, 1, 3]], t)
    interior = np.flatnonzero(np.all((p > 1e-9) & (p < 1 - 1e-9), axis=1))
    # jitter the interior points (the Kuhn cubes have coplanar faces around every vertex)
    p[interior] += np.random.default_rng(7).uniform(-0.12, 0.12, (interior.size, 3)) / n
    for c in range(len(t)):
        for j in range(4):
            v = t[c, j]
            if v not in interior:
                continue
            f = t[c, [k for k in range(4) if k != j]]
            nrm = np.cross(p[f[1]] - p[f[0]], p[f[2]] - p[f[0]])
            nrm /= np.linalg.norm(nrm)
            g = p[f].mean(axis=0)
            for frac in (1.05, 1.2, 1.5):
                q = p.copy()
                q[v] = g + (frac - 1) * (g - p[v])
                vol = _tet_volumes(q, t)
                if np.flatnonzero(vol < 0).tolist() == [c] and np.all(np.abs(vol) > 1e-6):
                    return q, t, int(c)
    raise RuntimeError("no foldable tetrahedron found")


def _jittered_square(n: int, seed: int = 3):
    """triangles(n) on the unit square with the interior points moved a little (no symmetry)."""
    p, t = triangles(n)
    p = p.astype(np.float64)
    inner = np.all((p > 1e-9) & (p < 1 - 1e-9), axis=1)
    p[inner] += np.random.default_rng(seed).uniform(-0.2, 0.2, (int(inner.sum()), 2)) / n
    return p, t


def fold_one_triangle(p, t):
    """Reflect, across its longest edge, the opposite vertex of the thinnest interior triangle whose
    reflection folds exactly that one triangle. Returns (points, folded cell id)."""
    p = np.asarray(p, dtype=np.float64)
    s = _signed_areas(p, t)
    t = np.where((s < 0)[:, None], t[:, ::-1], t)
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    key, cnt = np.unique(edges[:, 0] * len(p) + edges[:, 1], return_counts=True)
    boundary_nodes = np.unique(np.stack([key[cnt == 1] // len(p), key[cnt == 1] % len(p)]))
    L = np.stack(
        [np.linalg.norm(p[t[:, (j + 1) % 3]] - p[t[:, (j + 2) % 3]], axis=1) for j in range(3)], axis=1
    )
    thin = 2 * np.abs(_signed_areas(p, t)) / L.max(axis=1) ** 2
    for c in np.argsort(thin, kind="stable"):
        j = int(L[c].argmax())
        v, a, b = t[c, j], t[c, (j + 1) % 3], t[c, (j + 2) % 3]
        if v in boundary_nodes:
            continue
        d = p[b] - p[a]
        nrm = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        q = p.copy()
        q[v] = p[v] - 2 * np.dot(p[v] - p[a], nrm) * nrm
        if np.flatnonzero(_signed_areas(q, t) < 0).tolist() == [c]:
            return q, int(c)
    raise RuntimeError("no foldable triangle found")


def _z(p):
    return np.column_stack([p, np.zeros(len(p))]) if p.shape[1] == 2 else p


def corpus() -> dict:
    """name -> (points, [(cell type, array)], cell_data or None, file extension)."""
    out = {}
    p, t = _jittered_square(6)
    q, _ = fold_one_triangle(p, t)
    out["folded_sliver_2d"] = (q, [("triangle", t)], None, "vtu")
    pt, tt, _ = folded_tet(3)
    tt = tt.copy()
    tt[::3] = tt[::3][:, [0, 2, 1, 3]]
    out["folded_tet_3d"] = (pt, [("tetra", tt)], None, "vtu")
    extra = np.array([[5.0, 5.0], [-3.0, 2.0], [0.5, 0.5], [100.0, -100.0]])
    out["unused_points"] = (np.vstack([p, extra]), [("triangle", t)], None, "vtu")
    # two halves of the square, the points on x = 1/2 duplicated for the right half: a seam
    pq, qq = quads(6)
    pq = pq.astype(np.float64)
    right = pq[qq].mean(axis=1)[:, 0] > 0.5
    seam = np.flatnonzero(np.isclose(pq[:, 0], 0.5))
    copy = np.arange(len(pq))
    copy[seam] = len(pq) + np.arange(seam.size)
    qs = qq.copy()
    qs[right] = copy[qq[right]]
    out["duplicate_seam"] = (np.vstack([pq, pq[seam]]), [("quad", qs)], None, "vtu")
    # two squares of triangles touching at one corner (1, 1)
    p1, t1 = triangles(3)
    corner = int(np.flatnonzero(np.all(p1 == 1.0, axis=1))[0])
    t2 = t1 + len(p1)
    t2[t2 == len(p1) + int(np.flatnonzero(np.all(p1 == 0.0, axis=1))[0])] = corner  # (1, 1) is shared
    out["pinch"] = (np.vstack([p1, p1 + 1.0]), [("triangle", np.vstack([t1, t2]))], None, "vtu")
    # a 2x2 quad grid whose top-right quad is split in four: hanging nodes on two edges
    ph, qh = quads(2)
    ph = ph.astype(np.float64)
    tr = int(np.flatnonzero(np.all(ph[qh].mean(axis=1) > 0.5, axis=1))[0])
    a, b, c, d = qh[tr]
    mids = np.array(
        [
            (ph[a] + ph[b]) / 2,
            (ph[b] + ph[c]) / 2,
            (ph[c] + ph[d]) / 2,
            (ph[d] + ph[a]) / 2,
            ph[qh[tr]].mean(axis=0),
        ]
    )
    m0 = len(ph)
    ab, bc, cd, da, ce = m0, m0 + 1, m0 + 2, m0 + 3, m0 + 4
    fine = np.array([[a, ab, ce, da], [ab, b, bc, ce], [ce, bc, c, cd], [da, ce, cd, d]])
    out["hanging_node"] = (
        np.vstack([ph, mids]),
        [("quad", np.vstack([np.delete(qh, tr, axis=0), fine]))],
        None,
        "vtu",
    )
    # three separate squares
    pieces_p, pieces_t = [], []
    for i, (dx, dy) in enumerate([(0, 0), (2, 0), (0, 3)]):
        pp, tq = triangles(3)
        pieces_p.append(pp + [dx, dy])
        pieces_t.append(tq + 16 * i)
    out["disconnected"] = (np.vstack(pieces_p), [("triangle", np.vstack(pieces_t))], None, "vtu")
    # a zero-area triangle (three collinear points) in a fan
    pz = np.array([[0, 0], [1, 0], [2, 0], [1, 1], [0, 1]], dtype=np.float64)
    out["zero_area"] = (
        pz,
        [("triangle", np.array([[0, 1, 3], [1, 2, 3], [0, 3, 4], [0, 2, 1]]))],
        None,
        "vtk",
    )
    # triangles exported as quads with a repeated last corner (collapsed quads), next to real quads
    pm, blocks = mixed_2d(4)
    tris = blocks[1][1]
    out["repeated_vertex"] = (pm, [("quad", np.vstack([blocks[0][1], tris[:, [0, 1, 2, 2]]]))], None, "vtu")
    # a triangle with a repeated vertex: nothing left of it
    pr, tr2 = triangles(2)
    tr2 = tr2.copy()
    tr2[3] = [tr2[3, 0], tr2[3, 0], tr2[3, 1]]
    out["repeated_vertex_triangle"] = (pr, [("triangle", tr2)], None, "vtk")
    # three triangles on one edge (an overlapping flap): not a manifold
    pn = np.array([[0, 0], [1, 0], [0.5, 1], [0.5, -1], [0.4, 0.5]], dtype=np.float64)
    out["nonmanifold_edge"] = (pn, [("triangle", np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))], None, "vtu")
    # hexahedra with warped faces (interior points moved out of their planes)
    phx, hx = hexes(3)
    phx = phx.astype(np.float64)
    inner = np.all((phx > 1e-9) & (phx < 1 - 1e-9), axis=1)
    phx[inner] += np.random.default_rng(5).uniform(-0.08, 0.08, (int(inner.sum()), 3))
    out["nonplanar_quads"] = (phx, [("hexahedron", hx)], None, "vtu")
    # the folded sliver mesh far from the origin (cells ~1e-3) and at micro scale (~1e-9)
    out["far_from_origin"] = (q * 6e-3 + np.array([1.0e6, -2.0e6]), [("triangle", t)], None, "vtu")
    out["micro_scale"] = (q * 6e-9, [("triangle", t)], None, "vtu")
    # tetrahedra plus triangles that are no face of them (a stray surface) and a boundary face
    pt3, t3 = tets(2)
    face = t3[:1, :3]
    pts3 = np.vstack([pt3, [[2.0, 2.0, 2.0], [3.0, 2.0, 2.0], [2.0, 3.0, 2.0]]])
    stray = np.array([[len(pt3), len(pt3) + 1, len(pt3) + 2], [0, 2, 8]])
    out["mixed_2d_3d"] = (pts3, [("tetra", t3), ("triangle", np.vstack([stray, face]))], None, "vtu")
    # a triangulated piece of a cylinder: a surface in 3D space that is not planar
    ps, ts = triangles(4)
    ang = ps[:, 0] * np.pi / 2
    out["nonplanar_surface"] = (
        np.column_stack([np.cos(ang), np.sin(ang), ps[:, 1]]),
        [("triangle", ts)],
        None,
        "vtu",
    )
    return out


def normalized(name: str):
    """The far/micro meshes' reference: the same mesh at the origin with unit-size coordinates."""
    p, t = _jittered_square(6)
    q, _ = fold_one_triangle(p, t)
    return q, [("triangle", t)]


def write_corpus(folder: str = OUT) -> list[str]:
    os.makedirs(folder, exist_ok=True)
    written = []
    for name, (pts, cells, cell_data, ext) in corpus().items():
        path = os.path.join(folder, f"{name}.{ext}")
        mesh = meshio.Mesh(_z(np.asarray(pts, dtype=np.float64)), cells, cell_data=cell_data or {})
        meshio.write(path, mesh, binary=(ext == "vtu")) if ext == "vtu" else meshio.write(
            path, mesh, binary=False
        )
        written.append(path)
    return written


if __name__ == "__main__":
    for path in write_corpus():
        print(path, os.path.getsize(path))
