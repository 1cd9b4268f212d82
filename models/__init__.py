"""MAGNET agglomeration library: mesh I/O, dual graph, geometry, partitioners, merging, metrics.

The public face (docs/python.md):

    from models import agglomerate, build_hierarchy, read_mesh, check

Lazy: `import models` loads nothing else; numpy and the rest come with the first function used.
This package knows nothing of HTTP or Celery. Everything is numpy arrays.
"""

__version__ = "0.1.0"
__all__ = ["agglomerate", "build_hierarchy", "read_mesh", "check", "Agglomeration", "Hierarchy"]


def __getattr__(name: str):
    if name in __all__:
        import importlib

        return getattr(importlib.import_module("models.agglomeration"), name)
    raise AttributeError(f"module 'models' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *__all__])
