"""Graph helpers that know nothing of meshes: CSR utilities, the GraphBatch container and the compiled
_fastgraph module. Imports only models.errors and models.native; everything above may import it."""
