"""Writers of agglomerated meshes: VTU (ParaView), lymph (Matlab PolyDG) and deal.II UCD. Imports mesh
and polytope; imported by hierarchy, the pipeline and the CLI."""
