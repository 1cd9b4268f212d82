"""Merging parts into polygons (2D) and polyhedra (3D), with holes and cavities found. Imports
models.mesh and models.graph; imported by quality, export, hierarchy and the pipeline."""
