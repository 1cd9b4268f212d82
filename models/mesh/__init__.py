"""The fine mesh: the Mesh/PolyMesh containers, cell geometry, the dual graph, orientation, boundary
groups, the mesh check and one reader per format family. Imports only models.errors and models.native."""
