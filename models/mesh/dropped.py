"""What a read left out, and the sentences that say it: a few bad cells among many are left out
and reported, not refused (few_bad, record_dropped, dropped_sentence); cells of lower dimension read
and not used (ignored_lower_sentence). Used by models.mesh.build and the readers, and by the
pipeline, the API and the CLI to say it."""

from __future__ import annotations

import numpy as np

from models.errors import id_list
from models.mesh.container import Mesh


def few_bad(n_bad: int, n: int) -> bool:
    """A few bad cells among many (non-negotiable: agglomerated and reported, not refused): at most
    1% of the cells, so a mesh of fewer than 100 cells has none to spare."""
    return 0 < n_bad <= n // 100


def record_dropped(mesh: Mesh, dropped: list, n_before: int) -> None:
    """mesh.meta["dropped_cells"]: per reason the ids of the cells left out ("reasons"), all of them
    ("ids_all"), in the numbering of the file's cells (of the mesh's dimension) before any was left
    out, and that count ("file_cells"). A second call (degenerate cells after cells with missing
    points) maps its ids, counted among the cells kept so far, back to the file's."""
    old = mesh.meta.get("dropped_cells") or {}
    first = np.asarray(old.get("ids_all", []), dtype=np.int64)
    before = np.setdiff1d(np.arange(n_before + first.size), first) if first.size else np.arange(n_before)
    reasons = dict(old.get("reasons", {}))
    ids_all = first.tolist()
    for why, ids in dropped:
        orig = before[np.asarray(ids, dtype=np.int64)]
        reasons[why] = reasons.get(why, []) + orig.tolist()
        ids_all += orig.tolist()
    mesh.meta["dropped_cells"] = {
        "ids_all": sorted(ids_all),
        "reasons": reasons,
        "file_cells": int(n_before + first.size),
    }


def left_out_info(meta: dict) -> dict | None:
    """What a mesh summary keeps of the cells the read left out: their file ids and the file's count
    (models.params checks a subset's file ids against them), or None."""
    left_out = meta.get("dropped_cells")
    return {k: left_out[k] for k in ("ids_all", "file_cells")} if left_out else None


def read_ids(meta: dict, file_ids) -> np.ndarray:
    """Each file cell id (0 <= id < the file's count) as the id of the cell read: -1 for those left out."""
    ids = np.asarray(file_ids, dtype=np.int64)
    left_out = meta.get("dropped_cells")
    if not left_out:
        return ids
    out = np.full(int(left_out["file_cells"]), -1, dtype=np.int64)
    out[_kept(left_out)] = np.arange(int(left_out["file_cells"]) - len(left_out["ids_all"]))
    return out[ids]


def _kept(left_out: dict) -> np.ndarray:
    """The file ids of the cells read."""
    return np.setdiff1d(
        np.arange(int(left_out["file_cells"])), np.asarray(left_out["ids_all"], dtype=np.int64)
    )


def file_labels(meta: dict, labels: np.ndarray) -> np.ndarray:
    """One label per cell of the file (or of cells= as given): -1 for the few bad cells the read
    left out (meta["dropped_cells"]); `labels` (one per cell read) where none was."""
    left_out = meta.get("dropped_cells")
    if not left_out:
        return labels
    full = np.full(int(left_out["file_cells"]), -1, dtype=np.int64)
    full[_kept(left_out)] = labels
    return full


def read_labels(meta: dict, labels: np.ndarray) -> np.ndarray:
    """file_labels undone: the labels of the cells read, from one per cell of the file (a level's
    labels.json as written); other arrays as they are."""
    left_out = meta.get("dropped_cells")
    if not left_out or labels.size != int(left_out["file_cells"]):
        return labels
    return labels[_kept(left_out)]


def ignored_lower_sentence(meta: dict, dim: int) -> str:
    """The cells two or more dimensions below the mesh's (lines and points of a volume mesh, points
    of a planar one): read, counted and not used (only the faces of the mesh's cells are boundary
    groups); '' where there are none."""
    lower = meta.get("lower_dim_cells") or {}

    def below(name: str) -> bool:
        kind = name.replace("poly-", "")
        return kind.startswith("vertex") or (dim == 3 and kind.startswith("line"))

    kept = {name: int(n) for name, n in lower.items() if below(str(name)) and n}
    empty = int(lower.get("empty cell", 0))  # (VTK_EMPTY_CELL: no points at all)
    said = [f"{empty:,} empty cell{'s' if empty > 1 else ''} (no points) ignored"] if empty else []
    if kept:
        total = sum(kept.values())
        kinds = ", ".join(f"{n:,} {name}" for name, n in sorted(kept.items()))
        faces = "triangles and quadrilaterals" if dim == 3 else "edges"
        said.append(
            f"{total:,} cells of lower dimension ignored ({kinds}): only the faces of the mesh's cells "
            f"({faces}) become boundary groups"
        )
    return "; ".join(said)


def dropped_sentence(meta: dict) -> str | None:
    """One sentence on the cells a read left out, or None."""
    d = meta.get("dropped_cells")
    if not d:
        return None
    parts = [
        f"{len(ids):,} {why} (cell{'s' if len(ids) > 1 else ''} {id_list(ids)})"
        for why, ids in d["reasons"].items()
    ]
    return (
        f"{len(d['ids_all']):,} of the file's {d['file_cells']:,} cells left out, the rest agglomerated: "
        + "; ".join(parts)
    )
