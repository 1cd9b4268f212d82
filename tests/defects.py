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
from meshes import tets  # noqa: E402

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
    p2 = p[:, :2]
    # orient consistently first (by own sign: the file is a valid, unfolded mesh)
    s = _signed_areas(p2, t)
    t_file = t
    t = np.where((s < 0)[:, None], t[:, ::-1], t)
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    key, cnt = np.unique(edges[:, 0] * len(p) + edges[:, 1], return_counts=True)
    boundary_nodes = np.unique(np.stack([key[cnt == 1] // len(p), key[cnt == 1] % len(p)]))
    area = np.abs(_signed_areas(p2, t))
    L = np.stack([np.linalg.norm(p2[t[:, (j + 1) % 3]] - p2[t[:, (j + 2) % 3]], axis=1) for j in range(3)], axis=1)
    thin = 2 * area / L.max(axis=1) ** 2
    for c in np.argsort(thin, kind="stable"):
        j = int(L[c].argmax())  # the vertex opposite the longest edge
        v, a, b = t[c, j], t[c, (j + 1) % 3], t[c, (j + 2) % 3]
        if v in boundary_nodes:
            continue
        d = p2[b] - p2[a]
        n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        q = p.copy()
        q[v, :2] = p2[v] - 2 * np.dot(p2[v] - p2[a], n) * n
        neg = np.flatnonzero(_signed_areas(q[:, :2], t) < 0)
        if neg.tolist() == [c]:
            return q, t_file, int(c)
    raise RuntimeError("no foldable sliver found")


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
