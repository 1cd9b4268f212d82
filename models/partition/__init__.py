"""Partitioners (METIS, k-means, rtree, SAGE, RL), refiners (FM, flow, RL), coarsening and the agglomeration
modes. Imports graph, mesh and nets; imported by hierarchy, the pipeline and above. Neural ones load lazily."""

from __future__ import annotations

import importlib

from models.errors import ParameterError, listed
from models.graph.batch import GraphBatch
from models.partition.base import Partitioner

# name -> "module:factory"; the factory takes keyword options and returns a Partitioner.
REGISTRY: dict[str, str] = {
    "metis": "models.partition.metis:MetisPartitioner",
    "kmeans": "models.partition.kmeans:KMeansPartitioner",
    "rtree": "models.partition.rtree:RTreePartitioner",
    "sage-base": "models.partition.sage:SageBasePartitioner",
    "sage-hetero": "models.partition.sage:SageHeteroPartitioner",
    "rl-partitioner": "models.partition.rl:RLPartitioner",
}


def get_partitioner(name: str, **options) -> Partitioner:
    """Instantiate the partitioner called `name` (ParameterError if unknown)."""
    if name not in REGISTRY:
        raise ParameterError(f"unknown model {name!r}; choose one of {listed(sorted(REGISTRY))}")
    module, factory = REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), factory)(**options)


__all__ = ["GraphBatch", "Partitioner", "REGISTRY", "get_partitioner"]
