"""Partitioner registry. Neural partitioners are imported lazily (torch stays out of the service)."""

from __future__ import annotations

import importlib

from ..errors import ParameterError
from .base import GraphBatch, Partitioner

# name -> "module:factory"; the factory takes keyword options and returns a Partitioner.
REGISTRY: dict[str, str] = {
    "metis": "models.partitioners.metis:MetisPartitioner",
    "kmeans": "models.partitioners.kmeans:KMeansPartitioner",
    "rtree": "models.partitioners.rtree:RTreePartitioner",
    "sage-base": "models.partitioners.sage:SageBasePartitioner",
    "sage-hetero": "models.partitioners.sage:SageHeteroPartitioner",
    "rl-partitioner": "models.partitioners.rl:RLPartitioner",
}


def get_partitioner(name: str, **options) -> Partitioner:
    """Instantiate the partitioner called `name` (ParameterError if unknown)."""
    if name not in REGISTRY:
        raise ParameterError(f"unknown model {name!r}; choose one of {sorted(REGISTRY)}")
    module, factory = REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), factory)(**options)


__all__ = ["GraphBatch", "Partitioner", "REGISTRY", "get_partitioner"]
