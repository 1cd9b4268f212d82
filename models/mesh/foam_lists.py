"""An OpenFOAM case's cell addressing checked before VTK's reader builds it (constant/polyMesh's
owner and neighbour lists, ASCII or binary labelList).

VTK's reader believes them. A neighbour id corrupted into a large number made it build that many
cells, all but a few without a face, which we then refused as "cells without a volume"; two
neighbour lines swapped moved faces to the wrong cells, and 1% of the volume was read misplaced
with no word. OpenFOAM keeps its internal faces in upper-triangular order: each face's owner is the
lower cell, and the faces are sorted by owner, then by neighbour. Its checkMesh reports a case that
is not as an error, and every mesher and converter we know writes them so. So:
- a cell with fewer than 4 faces (a cell id past the mesh's cells) is refused, naming the list,
  the entry and the id;
- internal faces out of that order are said in a note (the case is read as VTK reads it).
"""

from __future__ import annotations

import os
import re

import numpy as np

_HEAD = re.compile(rb"FoamFile\s*\{(.*?)\}", re.S)
_COUNT = re.compile(rb"(?<![\w.])(\d+)\s*\(")


def read_labels(path: str) -> np.ndarray | None:
    """A labelList file's labels (ASCII, or binary with 32- or 64-bit labels), or None where it is
    not one we read (compressed, another layout): the caller then checks nothing."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError:
        return None
    head = _HEAD.search(data)
    header = head.group(1) if head else b""
    m = _COUNT.search(data, head.end() if head else 0)
    if m is None:
        return None
    n, start = int(m.group(1)), m.end()
    try:
        if re.search(rb"format\s+binary", header):
            kind = "<i8" if re.search(rb"label\s*=\s*64", header) else "<i4"
            out = np.frombuffer(data, dtype=kind, count=n, offset=start).astype(np.int64)
        else:
            end = data.find(b")", start)
            out = np.array(data[start:end].split(), dtype=np.int64)
    except ValueError:
        return None
    return out if out.size == n else None


def addressing_fault(case_folder: str) -> tuple[str | None, str | None]:
    """(a refusal, a note) about constant/polyMesh's owner and neighbour lists, each None where
    there is nothing to say (or the lists are not ones we read)."""
    mesh = os.path.join(case_folder, "constant", "polyMesh")
    owner = read_labels(os.path.join(mesh, "owner"))
    neighbour = read_labels(os.path.join(mesh, "neighbour"))
    if owner is None or neighbour is None or owner.size == 0 or neighbour.size > owner.size:
        return None, None
    if min(int(owner.min()), int(neighbour.min(initial=0))) < 0:
        return None, None  # (VTK's reader says what it says)
    n_cells = max(int(owner.max()), int(neighbour.max(initial=0))) + 1
    faces = np.bincount(owner, minlength=n_cells) + np.bincount(neighbour, minlength=n_cells)
    thin = np.flatnonzero(faces < 4)
    if thin.size:
        which, lst = (
            ("neighbour", neighbour)
            if neighbour.size and neighbour.max() == n_cells - 1
            else ("owner", owner)
        )
        at = int(np.flatnonzero(lst == n_cells - 1)[0])
        return (
            f"constant/polyMesh/{which}, entry {at:,}: cell {n_cells - 1:,}, but {thin.size:,} of the "
            f"{n_cells:,} cells that makes have fewer than 4 faces (a cell id past the mesh's cells: the "
            "list is corrupted)"
        ), None
    o = owner[: neighbour.size]
    bad = neighbour <= o
    step = (o[1:] < o[:-1]) | ((o[1:] == o[:-1]) & (neighbour[1:] <= neighbour[:-1]))
    n_bad = int(np.count_nonzero(bad)) + int(np.count_nonzero(step))
    if n_bad:
        return None, (
            f"{n_bad:,} internal faces of constant/polyMesh are out of OpenFOAM's upper-triangular order (each "
            "face owned by its lower cell, the faces sorted by owner, then neighbour; checkMesh reports this as "
            "an error): unless the case was written so on purpose, its owner or neighbour list may be "
            "corrupted, and cells may be read with the wrong faces"
        )
    return None, None
