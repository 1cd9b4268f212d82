"""MAGNET agglomeration library: mesh I/O, dual graph, geometry, partitioners, merging, metrics.

This package knows nothing of HTTP or Celery. Everything is numpy arrays.
"""

__version__ = "0.1.0"
