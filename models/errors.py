"""One exception type per failure kind at the library boundary (mapped to HTTP codes in service/)."""


class MagnetError(Exception):
    """Base class of every error the library raises on purpose."""


class MeshError(MagnetError):
    """The mesh cannot be read or is not a valid mesh (broken file, NaN, degenerate cells, ...)."""


class HoleError(MeshError):
    """Agglomerated elements enclose a hole that the hole policy refuses or the cuts could not remove:
    found after the mesh was read (no reader's failure: the CLI does not name a reader for it)."""


class ParameterError(MagnetError):
    """A parameter is out of range or inconsistent with the mesh (k too large, unknown mode, ...)."""


class ModelError(MagnetError):
    """An agglomeration model cannot be used (weights missing, wrong dimension, ...)."""


def id_list(ids, limit: int = 5) -> str:
    """Ids as a message says them: "3, 17, 40" (the first `limit`, then ", ..." where there are
    more), never a Python list."""
    ids = [int(i) for i in list(ids)[: limit + 1]]
    more = len(ids) > limit
    return ", ".join(str(i) for i in ids[:limit]) + (", ..." if more else "")


def listed(items) -> str:
    """Names as a message says them: "metis, kmeans, rtree" (no brackets, no quotes)."""
    return ", ".join(str(x) for x in items)
