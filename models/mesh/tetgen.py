"""Shewchuk's Triangle (2D) and Si's TetGen (3D) meshes: a `.node` file of points and a `.ele`
file of elements with the same stem, as `triangle -pq` and `tetgen -pq` write them.

meshio's reader knows TetGen's tetrahedra only: a Triangle mesh (2D points, triangles) was
refused as "corrupted". Read here, either given as its .ele or its .node:

- `.node`: a header `points dim attributes markers`, then `id x y [z] [attributes...] [marker]`;
- `.ele`: a header `elements nodes_per_element attributes`, then `id n1 n2 ... [attributes...]`:
  triangles of 3 or 6 nodes (2D), tetrahedra of 4 or 10 (3D), agglomerated on their corners;
- numbering from 0 or from 1, as the first point's id says (both tools write either);
- `#` comments anywhere; the first element attribute (TetGen's and Triangle's region attribute,
  `-A`) is the physical group where it holds whole numbers.
The numbers are split and converted by numpy, not parsed line by line.
"""

from __future__ import annotations

import os
import re

import numpy as np

from models.errors import MeshError
from models.mesh.abaqus import is_number

_COMMENT = re.compile(r"#[^\n]*")
# the extra nodes of a 6-node triangle (Triangle: opposite corners 1, 2, 3) in VTK's order
# (mid-edges 01, 12, 20); TetGen's 10-node tetrahedra list theirs as VTK does
_TRIANGLE6 = [0, 1, 2, 5, 3, 4]


def _table(path: str, what: str) -> tuple[list[float], np.ndarray]:
    """(the header's numbers, the rest of the file's numbers, flat)."""
    try:
        with open(path, "rb") as fh:
            text = _COMMENT.sub("", fh.read().decode("utf-8", "replace"))
    except OSError:
        raise MeshError(f"its {what} file {os.path.basename(path)} cannot be opened") from None
    first, _, rest = text.strip().partition("\n")
    try:
        head = [float(t) for t in first.split()]
        body = np.array(rest.split(), dtype=np.float64)
    except ValueError:
        bad = next((t for t in (first + " " + rest).split() if not is_number(t)), "?")
        raise MeshError(f"its {what} file holds {bad[:40]!r} where a number is expected") from None
    if not head or any(h != int(h) or h < 0 for h in head):
        raise MeshError(f"its {what} file does not start with a header of counts")
    return head, body


def _rows(body: np.ndarray, n: int, width: int, what: str) -> np.ndarray:
    if body.size < n * width:
        raise MeshError(
            f"its {what} file announces {n:,} rows of {width} numbers and holds {body.size:,} numbers "
            "(is it truncated?)"
        )
    return body[: n * width].reshape(n, width)


def read_tetgen(path: str):
    """The mesh of a .ele / .node pair (either given) as a meshio.Mesh."""
    import meshio

    stem, ext = os.path.splitext(os.fspath(path))
    node_path, ele_path = stem + ".node", stem + ".ele"
    if not os.path.isfile(ele_path):
        raise MeshError(
            f"a .node file holds points only, and {os.path.basename(ele_path)} (its elements) is not beside it"
            if ext.lower() == ".node"
            else f"its points' file {os.path.basename(node_path)} is not beside it"
        )
    if not os.path.isfile(node_path):
        raise MeshError(f"its points' file {os.path.basename(node_path)} is not beside it")
    head, body = _table(node_path, ".node")
    n, dim = int(head[0]), int(head[1]) if len(head) > 1 else 3
    attrs = int(head[2]) if len(head) > 2 else 0
    markers = int(head[3]) if len(head) > 3 else 0
    if dim not in (2, 3):
        raise MeshError(f"its .node file gives points of dimension {dim}; Triangle's are 2, TetGen's 3")
    rows = _rows(body, n, 1 + dim + attrs + min(markers, 1), ".node")
    ids = rows[:, 0].astype(np.int64)
    points = rows[:, 1 : 1 + dim]
    head, body = _table(ele_path, ".ele")
    m = int(head[0])
    per = int(head[1]) if len(head) > 1 else (3 if dim == 2 else 4)
    eattrs = int(head[2]) if len(head) > 2 else 0
    kinds = {(2, 3): "triangle", (2, 6): "triangle6", (3, 4): "tetra", (3, 10): "tetra10"}
    kind = kinds.get((dim, per))
    if kind is None:
        raise MeshError(
            f"its elements have {per} nodes each: {'triangles of 3 or 6' if dim == 2 else 'tetrahedra of 4 or 10'} "
            f"are read ({dim}D points)"
        )
    table = _rows(body, m, 1 + per + eattrs, ".ele")
    nodes = table[:, 1 : 1 + per].astype(np.int64)
    if kind == "triangle6":
        nodes = nodes[:, _TRIANGLE6]
    base = int(ids.min()) if ids.size else 0
    if ids.size and not np.array_equal(ids, np.arange(base, base + ids.size)):  # ids in any order
        order = np.argsort(ids, kind="stable")
        pos = np.searchsorted(ids[order], nodes)
        pos = np.minimum(pos, ids.size - 1)
        nodes = np.where(ids[order][pos] == nodes, order[pos], -1)
    else:
        nodes = nodes - base  # (a missing point: said by the mesh's checks)
    cell_data = {}
    if eattrs:
        region = table[:, 1 + per]
        if np.all(region == np.round(region)):
            cell_data["material"] = [region.astype(np.int64)]
    return meshio.Mesh(points, [(kind, nodes)], cell_data=cell_data)
