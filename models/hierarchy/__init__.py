"""Nested hierarchies of agglomerates for multigrid, their statistics and files, and mgcheck (a real
pyamg solve). Imports partition, polytope, quality and export; imported by the pipeline, api and CLI."""
