"""Abaqus input files (.inp), flat or as Abaqus/CAE writes them: parts, an assembly, instances.

meshio's reader knows only flat files: a second *NODE block replaces the first one's points, so a
file of two parts (every Abaqus/CAE model of more than one part) had its first part's cells point
at the second part's nodes, and *INSTANCE placements were ignored. This reader follows the file's
structure:

- *PART ... *END PART: a part's nodes, elements and element sets, numbered within the part;
- *ASSEMBLY ... *END ASSEMBLY: each *INSTANCE of a part is that part placed by the instance's data
  lines (a translation; then a rotation about the axis through two points, by an angle in
  degrees, applied after the translation, as Abaqus does). A part that is instanced twice is
  there twice; a part no instance names is not in the model. Nodes and elements written inside an
  *INSTANCE block (an independent instance, whose part is empty) are that instance's mesh, placed
  the same way; an assembly's *ELSET with INSTANCE= is a set of that instance's elements;
- a file without parts is one model: all its *NODE blocks together (meshio kept the last one).

Groups: the element sets (*ELSET and *ELEMENT's ELSET=). With several instances, each instance
is a group of its name, and a part's sets that hold only some of its elements are "instance.set".
Each cell goes to the smallest set that holds it: a set of every element (EALL, CAE's Set-1) does
not hide the materials inside it.

*INCLUDE and INPUT= files are read from the main file's folder (never from outside it). Element
types: meshio's table, widened by models.mesh.abaqus_types; a type no table knows is read as the
point (MASS, ROTARYI, ...) or connector (two nodes) it is when its rows say so, otherwise named in
the refusal. The numbers of each block are split and converted by numpy, not parsed line by line.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from models.errors import MeshError
from models.mesh import abaqus_types

_COMMENT = re.compile(r"^[ \t]*\*\*[^\n]*(\n|$)", re.MULTILINE)
_KEYWORD = re.compile(r"^[ \t]*\*([^\n]*)", re.MULTILINE)
_INCLUDE_DEPTH = 8


@dataclass
class _Part:
    name: str
    node_ids: list = field(default_factory=list)
    node_xyz: list = field(default_factory=list)
    blocks: list = field(default_factory=list)  # (meshio type, element ids, node ids)
    sets: dict = field(default_factory=dict)  # set name (as written) -> element ids

    def elements(self) -> np.ndarray:
        ids = [b[1] for b in self.blocks]
        return np.concatenate(ids) if ids else np.zeros(0, np.int64)


def _params(line: str) -> tuple[str, dict]:
    """'*Element, type=C3D8R, elset=A' -> ('ELEMENT', {'TYPE': 'C3D8R', 'ELSET': 'A'})."""
    items = [s.strip() for s in line.split(",")]
    keyword = items[0].upper()
    out = {}
    for item in items[1:]:
        if not item:
            continue
        key, eq, value = item.partition("=")
        out[key.strip().upper()] = value.strip().strip('"') if eq else True
    return keyword, out


def _blocks(path: str, text: str, folder: str, depth: int = 0):
    """(keyword, params, data text, line number) for every keyword of the file, includes inlined."""
    text = _COMMENT.sub("", text.replace("\r\n", "\n"))
    heads = list(_KEYWORD.finditer(text))
    for i, m in enumerate(heads):
        keyword, params = _params(m.group(1))
        end = heads[i + 1].start() if i + 1 < len(heads) else len(text)
        data = text[m.end() + 1 : end]
        line = text.count("\n", 0, m.start()) + 1
        if keyword == "INCLUDE" or isinstance(params.get("INPUT"), str):
            other = _included(path, params.get("INPUT"), folder, line)
            if keyword == "INCLUDE":
                if depth >= _INCLUDE_DEPTH:
                    raise MeshError(f"*INCLUDE at line {line} nests deeper than {_INCLUDE_DEPTH} files")
                yield from _blocks(other, _text(other), folder, depth + 1)
                continue
            data = _COMMENT.sub("", _text(other).replace("\r\n", "\n")) + data
        yield keyword, params, data, line


def _included(path: str, name, folder: str, line: int) -> str:
    if not isinstance(name, str) or not name:
        raise MeshError(f"*INCLUDE at line {line} names no INPUT= file")
    target = os.path.realpath(os.path.join(os.path.dirname(path), name))
    if os.path.commonpath([target, folder]) != folder:
        raise MeshError(f"line {line} includes {name}, which is outside the file's folder")
    if not os.path.isfile(target):
        raise MeshError(
            f"line {line} includes {name}, which is not beside it (give it too: over HTTP, both in one "
            ".zip or .tar.gz)"
        )
    return target


def _text(path: str) -> str:
    with open(path, "rb") as fh:
        return fh.read().decode("utf-8", "replace")


def _numbers(data: str, dtype, line: int, what: str) -> np.ndarray:
    tokens = data.replace(",", " ").split()
    try:
        return np.array(tokens, dtype=np.float64).astype(dtype, copy=False)
    except ValueError:
        bad = next(t for t in tokens if not is_number(t))
        raise MeshError(f"{what} from line {line} holds {bad[:40]!r} where a number is expected") from None


def is_number(token: str) -> bool:
    """The token reads as a number (Python's float: the same rule as numpy's conversion)."""
    try:
        float(token)
    except ValueError:
        return False
    return True


def _nodes(part: _Part, data: str, line: int) -> None:
    rows = [r for r in data.split("\n") if r.strip()]
    if not rows:
        return
    width = len([t for t in rows[0].replace(",", " ").split()])
    flat = _numbers(data, np.float64, line, "the *NODE block")
    if width not in (3, 4) or flat.size % width:
        width = max(len(r.replace(",", " ").split()) for r in rows)
        if width not in (3, 4):
            raise MeshError(f"the *NODE block from line {line} has rows of {width} numbers (id, x, y[, z])")
        rows = [np.array(r.replace(",", " ").split(), float) for r in rows]
        flat = np.concatenate([np.pad(r, (0, width - r.size)) for r in rows])
    table = flat.reshape(-1, width)
    xyz = np.zeros((table.shape[0], 3))
    xyz[:, : width - 1] = table[:, 1:]
    part.node_ids.append(table[:, 0].astype(np.int64))
    part.node_xyz.append(xyz)


_TYPE_FIX = {"tetra4": "tetra"}  # (meshio's table names C3D4H so; no such meshio cell)


def _elements(part: _Part, params: dict, data: str, line: int, unknown: set) -> None:
    from meshio._common import num_nodes_per_cell
    from meshio.abaqus._abaqus import abaqus_to_meshio_type

    etype = str(params.get("TYPE", "")).upper()
    if not etype:
        raise MeshError(f"the *ELEMENT at line {line} has no TYPE=")
    flat = _numbers(data, np.int64, line, f"the *ELEMENT, TYPE={etype} block")
    if not flat.size:
        return
    cell = abaqus_to_meshio_type.get(etype)
    cell = _TYPE_FIX.get(cell, cell)
    if cell is None:
        first = data.strip().split("\n", 1)[0].replace(",", " ").split()
        cell = {2: "vertex", 3: "line"}.get(len(first))
        if cell is None:
            unknown.add(etype)
            return
    width = num_nodes_per_cell[cell] + 1
    if flat.size % width:
        raise MeshError(
            f"the *ELEMENT, TYPE={etype} block from line {line} holds {flat.size} numbers, not rows of "
            f"an id and {width - 1} nodes"
        )
    table = flat.reshape(-1, width)
    part.blocks.append((cell, table[:, 0], table[:, 1:]))
    name = params.get("ELSET")
    if isinstance(name, str):
        part.sets.setdefault(name, []).append(table[:, 0])


def _set_ids(data: str, params: dict, known: dict, line: int) -> np.ndarray:
    tokens = data.replace(",", " ").split()
    if not tokens:
        return np.zeros(0, np.int64)
    if not all(is_number(t) for t in tokens):  # a set of sets
        return np.concatenate(
            [np.zeros(0, np.int64)] + [np.concatenate(known.get(t, [])) for t in tokens if known.get(t)]
        )
    ids = np.array(tokens, np.float64).astype(np.int64)
    if params.get("GENERATE"):
        if ids.size % 3 and ids.size % 3 != 2:
            raise MeshError(f"the *ELSET, GENERATE from line {line} is not rows of first, last[, step]")
        rows = ids.reshape(-1, 3) if ids.size % 3 == 0 else np.append(ids, 1).reshape(-1, 3)
        return np.concatenate([np.arange(a, b + 1, max(s, 1)) for a, b, s in rows])
    return ids


def _rotation(data: str, line: int) -> tuple[np.ndarray, np.ndarray]:
    """An *INSTANCE's placement: x -> R (x + t - a) + a."""
    rows = [r.replace(",", " ").split() for r in data.split("\n") if r.strip()]
    try:
        t = np.zeros(3)
        if rows:
            v = np.array(rows[0], float)[:3]
            t[: v.size] = v
        rot = np.eye(3), np.zeros(3)
        if len(rows) > 1:
            v = np.array(rows[1], float)
            if v.size < 7:
                raise ValueError
            a, b, angle = v[:3], v[3:6], np.radians(v[6])
            axis = b - a
            norm = np.linalg.norm(axis)
            if norm == 0:
                raise ValueError
            k = axis / norm
            kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
            r = np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx
            rot = r, a
    except ValueError:
        raise MeshError(
            f"the *INSTANCE at line {line} is placed by rows that are not a translation (x, y, z) and "
            "a rotation (two points and an angle)"
        ) from None
    r, a = rot
    return r, r @ (t - a) + a


def read_abaqus(path: str):
    """The file as one meshio.Mesh (points, a cell block per part instance and type, cell_sets)."""
    import meshio

    abaqus_types.extend()
    path = os.fspath(path)
    folder = os.path.realpath(os.path.dirname(path)) or "/"
    parts: dict[str, _Part] = {}
    flat = _Part("")
    instances = []  # (name, part key, its own _Part, R, t)
    where = "model"
    current = flat
    unknown: set = set()
    for keyword, params, data, line in _blocks(path, _text(path), folder):
        if keyword == "PART":
            name = str(params.get("NAME", f"part-{len(parts) + 1}"))
            current = parts.setdefault(name.upper(), _Part(name))
            where = "part"
        elif keyword in ("END PART", "END INSTANCE"):
            current, where = (flat, "model") if keyword == "END PART" else (None, "assembly")
        elif keyword == "ASSEMBLY":
            current, where = None, "assembly"
        elif keyword == "END ASSEMBLY":
            current, where = flat, "model"
        elif keyword == "INSTANCE":
            name = str(params.get("NAME", f"instance-{len(instances) + 1}"))
            key = str(params.get("PART", "")).upper()
            if key and key not in parts:
                raise MeshError(
                    f"the *INSTANCE {name} at line {line} places part {params['PART']}, which the file does not define"
                )
            own = _Part(name)  # nodes and elements written inside the block (an independent
            # instance: its part is empty), and the assembly's sets of this instance
            instances.append((name, key, own, *_rotation(data, line)))
            current, where = own, "instance"
        elif keyword == "NODE" and current is not None:
            _nodes(current, data, line)
        elif keyword == "ELEMENT" and current is not None:
            _elements(current, params, data, line, unknown)
        elif keyword == "ELSET" and isinstance(params.get("ELSET"), str):
            target = current
            if where == "assembly" and isinstance(params.get("INSTANCE"), str):
                target = next(
                    (own for n, _, own, *_ in instances if n.upper() == params["INSTANCE"].upper()), None
                )
            if target is not None:
                ids = _set_ids(data, params, target.sets, line)
                target.sets.setdefault(params["ELSET"], []).append(ids)
    placed = [(flat.name, flat, np.eye(3), np.zeros(3))] if flat.blocks else []
    placed += (
        [(n, _instance_part(parts.get(k), own), r, t) for n, k, own, r, t in instances]
        if instances
        else [(p.name, p, np.eye(3), np.zeros(3)) for p in parts.values()]
    )
    placed = [p for p in placed if p[1].blocks]
    if not placed:
        if unknown:
            raise MeshError(
                f"it holds elements of a type it does not know ({', '.join(sorted(unknown)[:6])})"
            )
        raise MeshError("it holds no *NODE and *ELEMENT blocks (is it an Abaqus input file?)")
    if unknown:
        raise MeshError(f"it holds elements of a type it does not know ({', '.join(sorted(unknown)[:6])})")
    return _assemble(meshio, placed, several=len(placed) > 1)


def _instance_part(base: _Part | None, own: _Part) -> _Part:
    """What an instance places: the mesh written inside its block where there is one (an
    independent instance), else its part's; its part's sets and the assembly's sets for it."""
    if own.blocks or base is None:
        return own
    sets = {name: list(chunks) for name, chunks in base.sets.items()}
    for name, chunks in own.sets.items():
        sets.setdefault(name, []).extend(chunks)
    return _Part(base.name, base.node_ids, base.node_xyz, base.blocks, sets)


def _assemble(meshio, placed, several: bool):
    points, cells, sets = [], [], {}
    offset = 0
    n_blocks = sum(len(p.blocks) for _, p, _, _ in placed)
    at = 0
    missing, total = [], sum(len(b[1]) for _, p, _, _ in placed for b in p.blocks)
    for name, part, r, t in placed:
        if not part.node_ids:
            raise MeshError(
                f"{'part ' + part.name if part.name else 'the model'} has elements but no *NODE block"
            )
        ids = np.concatenate(part.node_ids)
        xyz = np.concatenate(part.node_xyz)
        order = np.argsort(ids, kind="stable")
        ids, xyz = ids[order], xyz[order]
        last = np.r_[ids[1:] != ids[:-1], True]  # a node written twice: its last row (as meshio)
        ids, xyz = ids[last], xyz[last]
        points.append(xyz @ r.T + t)
        elements = part.elements()
        for cell, eids, conn in part.blocks:
            pos = np.searchsorted(ids, conn)
            pos = np.minimum(pos, ids.size - 1)
            found = ids[pos] == conn
            idx = np.where(found, pos + offset, -1)  # (a missing node: said by the mesh's checks)
            if not found.all():  # (elements of nodes no *NODE line defines: the first named)
                bad = ~found.reshape(len(found), -1).all(axis=1)
                missing.append((int(bad.sum()), int(np.asarray(eids)[bad][0]), int(conn[~found][0])))
            if cell == "line3" and idx.size and found.all():
                idx = _line3_ends_first(idx, xyz, offset)
            cells.append(meshio.CellBlock(cell, idx))
        starts = np.cumsum([0] + [len(b[1]) for b in part.blocks])
        e_order = np.argsort(elements, kind="stable")
        whole = set()
        for set_name, chunks in part.sets.items():
            members = np.unique(np.concatenate(chunks)) if chunks else np.zeros(0, np.int64)
            if several and members.size >= elements.size:
                whole.add(set_name)
                continue
            key = f"{name}.{set_name}" if several else set_name
            sets[key] = _per_block(members, elements, e_order, starts, at, n_blocks)
        if several:
            all_rows = np.arange(elements.size)
            sets[name] = _per_block(elements[all_rows], elements, e_order, starts, at, n_blocks)
        offset += ids.size
        at += len(part.blocks)
    if missing:
        from models.mesh.dropped import few_bad

        n = sum(m[0] for m in missing)
        if not few_bad(n, total):  # (a few are left out and said by the mesh's checks)
            raise MeshError(
                f"{n:,} of its {total:,} elements refer to nodes that no *NODE line defines (element "
                f"{missing[0][1]} refers to node {missing[0][2]}): a *NODE line is missing or the file is cut"
            )
    # (in the file's order: meshio_groups gives a cell to the smallest set holding it, numbers
    # the groups in this order)
    return meshio.Mesh(np.concatenate(points), cells, cell_sets=sets)


def _line3_ends_first(idx: np.ndarray, xyz: np.ndarray, offset: int) -> np.ndarray:
    """3-node lines as VTK and meshio number them (end, end, middle). Abaqus numbers them along the
    line (T3D3, B32: end, middle, end; gmsh's export too), meshio's writer as VTK: the block is read
    as the one its geometry shows, the two nodes farthest apart being the ends in most of its lines."""
    p = xyz[idx - offset]
    d01 = np.linalg.norm(p[:, 0] - p[:, 1], axis=1)
    d02 = np.linalg.norm(p[:, 0] - p[:, 2], axis=1)
    d12 = np.linalg.norm(p[:, 1] - p[:, 2], axis=1)
    along = (d02 > d01) & (d02 > d12)  # the first and third farthest apart: the second is the middle
    return idx[:, [0, 2, 1]] if np.count_nonzero(along) * 2 > along.size else idx


def _per_block(members, elements, e_order, starts, at, n_blocks) -> list:
    """meshio's cell_sets layout: one index array per cell block of the whole mesh."""
    sorted_ids = elements[e_order]
    pos = np.minimum(np.searchsorted(sorted_ids, members), max(sorted_ids.size - 1, 0))
    rows = e_order[pos[sorted_ids[pos] == members]] if sorted_ids.size else np.zeros(0, np.int64)
    out = [np.zeros(0, np.int64) for _ in range(n_blocks)]
    for b in range(len(starts) - 1):
        mine = rows[(rows >= starts[b]) & (rows < starts[b + 1])]
        out[at + b] = np.sort(mine - starts[b])
    return out
