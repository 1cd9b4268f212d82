"""Level files an earlier hierarchy left in a folder that the one written now does not write (an
outside sweep, session 47: a 4-level hierarchy written over a 6-level one kept level_4.* and
level_5.*, not nested with the new levels, without a word). Only files named as write_hierarchy
names them (level_<L>.<one of its suffixes>) go; nothing else in the folder is touched."""

from __future__ import annotations

import os
import re

# what write_hierarchy writes per level (models.hierarchy.nested), and nothing else
SUFFIXES = (
    "vtu",
    "labels.json",
    "parent.json",
    "metrics.json",
    "lymph.json",
    "lymph.mat",
    "agg.npz",
    "agg.mtx",
)
_NAME = re.compile(r"level_(0|[1-9][0-9]*)\.(" + "|".join(re.escape(s) for s in SUFFIXES) + r")")


def written_names(entries: list[dict]) -> set[str]:
    """The file names a hierarchy.json index's level entries name (operators included)."""
    names = set()
    for entry in entries:
        names.update(v for v in entry.values() if isinstance(v, str))
        agg = entry.get("aggregation") or {}
        names.update(agg.get(k) for k in ("npz", "mtx") if isinstance(agg.get(k), str))
    return names


def remove_stale(folder: str, keep: set[str]) -> list[str]:
    """Remove the plain files of `folder` named like a level's files (level_<L>.<suffix>) that are not
    in `keep` (the names just written); returns the names removed, by level. Links, folders and every
    other name are left alone; a file that cannot be removed is left too."""
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    removed = []
    for name in names:  # (a loop over the folder's entries, not over cells)
        if name in keep or _NAME.fullmatch(name) is None:
            continue
        path = os.path.join(folder, name)
        if os.path.islink(path) or not os.path.isfile(path):
            continue
        try:
            os.remove(path)
        except OSError:
            continue
        removed.append(name)
    return sorted(removed, key=lambda n: (int(_NAME.fullmatch(n).group(1)), n))


def removed_sentence(removed: list[str], folder: str) -> str:
    """One line for the files remove_stale removed (empty for none): how many, of which levels."""
    if not removed:
        return ""
    levels = sorted({int(_NAME.fullmatch(n).group(1)) for n in removed})
    which = ", ".join(f"level_{L}.*" for L in levels[:6]) + (", ..." if len(levels) > 6 else "")
    return (
        f"removed {len(removed)} file{'s' if len(removed) > 1 else ''} of an earlier hierarchy in {folder} "
        f"that this one does not write ({which})"
    )
