"""gmsh cells in two physical groups of the same dimension (a surface in both "all" and
"inclusion"), made one group per cell: the smallest group that holds the cell.

gmsh writes such a cell once with both groups (MSH 4: the entity lists both; meshio keeps the
first, so "inclusion" was lost without a word) or once per group (MSH 2: the same element twice,
which made the mesh "not a manifold"). Each cell is kept once, in its smallest group (the most
specific: the inclusion rather than the whole), and the reading says so in one line
(mesh.meta["overlapping_groups"], a `check` note).
"""

from __future__ import annotations

import numpy as np


def _block_sets(m) -> dict[int, list[str]]:
    """Block index -> the physical names (of the block's dimension) that hold the whole block."""
    out: dict[int, list[str]] = {}
    sets = getattr(m, "cell_sets", None) or {}
    for name, per_block in sets.items():
        if name.startswith("gmsh:") or name not in m.field_data:
            continue
        for k, idx in enumerate(per_block[: len(m.cells)]):
            if idx is not None and len(idx) == len(m.cells[k].data) and len(idx):
                out.setdefault(k, []).append(name)
    return out


def zero_is_no_group(m) -> None:
    """gmsh's physical tag 0 is no physical group (MSH 2 writes it for every element it saves
    outside one, as with Mesh.SaveAll): cells of a dimension below the mesh's with tag 0 are left
    out (they name no boundary group), and a tag array of zeros only is no tag array."""
    from meshio._mesh import topological_dimension

    tags = m.cell_data.get("gmsh:physical")
    if not tags or any(np.asarray(t).size and np.asarray(t).max() > 0 for t in tags):
        if tags:
            dims = [topological_dimension.get(c.type, 3) for c in m.cells]
            top = max(dims)
            for k, d in enumerate(dims):
                t = np.asarray(tags[k])
                if d < top and t.size and not t.any():
                    keep = t != 0
                    m.cells[k].data = np.asarray(m.cells[k].data)[keep]
                    for key in m.cell_data:
                        m.cell_data[key][k] = np.asarray(m.cell_data[key][k])[keep]
        return
    del m.cell_data["gmsh:physical"]
    dims = [topological_dimension.get(c.type, 3) for c in m.cells]
    top = max(dims)
    keep = [k for k, d in enumerate(dims) if d == top]  # (lower cells name no boundary group)
    m.cells = [m.cells[k] for k in keep]
    for key in list(m.cell_data):
        m.cell_data[key] = [m.cell_data[key][k] for k in keep]


def resolve_overlaps(m) -> str | None:
    """Give every cell of `m` (a meshio.Mesh read from gmsh) one physical group, the smallest of
    those that hold it; drop the repeats MSH 2 writes. Returns the sentence to say, or None."""
    tags = m.cell_data.get("gmsh:physical")
    if not tags:
        return None
    moved = _entity_overlaps(m, tags)
    dropped = _repeated_cells(m)
    if not moved and not dropped:
        return None
    n = moved + dropped
    return (
        f"{n:,} cells are in two or more physical groups of their dimension; each is kept once, in "
        "the smallest of them (the most specific)"
    )


def _entity_overlaps(m, tags) -> int:
    """MSH 4: blocks (gmsh entities) in several physical groups, by meshio's cell_sets."""
    held = {k: names for k, names in _block_sets(m).items() if len(names) > 1}
    if not held:
        return 0
    size: dict[str, int] = {}
    for name, per_block in m.cell_sets.items():
        if name in m.field_data:
            size[name] = sum(len(x) for x in per_block if x is not None)
    n = 0
    for k, names in held.items():
        best = min(names, key=lambda s: (size.get(s, 0), s))
        tag = int(m.field_data[best][0])
        block = np.asarray(tags[k])
        n += int(np.count_nonzero(block != tag))
        tags[k] = np.full(block.shape, tag, dtype=block.dtype)
    return n


def _repeated_cells(m) -> int:
    """MSH 2: the same element written once per group (same type, same nodes, another physical
    tag). The copies are dropped; the one kept carries the smallest group's tag."""
    tags = m.cell_data["gmsh:physical"]
    by_type: dict[str, list[int]] = {}
    for k, block in enumerate(m.cells):
        by_type.setdefault(block.type, []).append(k)
    counts = np.bincount(np.concatenate([np.asarray(t, np.int64) for t in tags]).clip(0))
    dropped = 0
    for blocks in by_type.values():
        rows = np.concatenate([np.sort(np.asarray(m.cells[k].data), axis=1) for k in blocks])
        if rows.shape[0] < 2:
            continue
        tag = np.concatenate([np.asarray(tags[k], np.int64) for k in blocks])
        _, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        if first.size == rows.shape[0]:
            continue
        # cells written with two different tags (a copy with its own tag again is another fault,
        # left to the mesh's checks): per such cell, the row of its smallest group is kept
        lo = np.full(first.size, np.iinfo(np.int64).max)
        hi = np.full(first.size, np.iinfo(np.int64).min)
        np.minimum.at(lo, inverse, tag)
        np.maximum.at(hi, inverse, tag)
        mixed = (lo != hi)[inverse]
        if not mixed.any():
            continue
        size = counts[tag.clip(0)]
        order = np.lexsort((tag, size, inverse))  # by cell, then the smallest group first
        keep_row = order[np.r_[True, inverse[order][1:] != inverse[order][:-1]]]
        keep = ~mixed
        keep[keep_row] = True
        starts = np.cumsum([0] + [len(m.cells[k].data) for k in blocks])
        for j, k in enumerate(blocks):
            mine = keep[starts[j] : starts[j + 1]]
            if mine.all():
                continue
            block = m.cells[k]
            block.data = np.asarray(block.data)[mine]
            for key in list(m.cell_data):
                m.cell_data[key][k] = np.asarray(m.cell_data[key][k])[mine]
            dropped += int(np.count_nonzero(~mine))
    return dropped
