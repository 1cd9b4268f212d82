"""Abaqus element types meshio's reader lacks, added to its table by the shape of their nodes.

meshio's Abaqus reader knows some 60 element types and exits (SystemExit, after printing "Element
type not available") on any other: outside sweep S met plane-strain CPE4 refused as "corrupted".
Abaqus names an element by its family, its nodes and its options (reduced integration R, hybrid H,
incompatible modes I, modified M, coupled temperature T, ...); what matters here is the shape its
nodes make. `extend()` adds the common continuum, heat-transfer and axisymmetric types to meshio's
table (by that shape; called before every Abaqus read: models.mesh.abaqus).
"""

from __future__ import annotations

# meshio's cell type -> Abaqus types of that shape
_MORE = {
    "triangle": "CPE3 CPE3H CPS3 CAX3 CAX3H CPEG3 CPEG3H DC2D3 DCAX3 CPE3T CPS3T CAX3T",
    "quad": (
        "CPE4 CPE4H CPE4I CPE4IH CPE4R CPE4RH CPE4T CPE4RT CPS4 CPS4I CPS4R CPS4T CPS4RT CAX4 CAX4H "
        "CAX4I CAX4IH CAX4R CAX4RH CAX4T CAX4RT CPEG4 CPEG4H CPEG4I CPEG4R CPEG4RH DC2D4 DCAX4"
    ),
    "triangle6": "CPE6 CPE6H CPE6M CPE6MH CPS6 CPS6M CAX6 CAX6H CAX6M CAX6MH CPEG6 CPEG6M DC2D6 DCAX6",
    "quad8": (
        "CPE8 CPE8H CPE8R CPE8RH CPE8T CPE8RT CPS8 CPS8R CPS8T CPS8RT CAX8 CAX8H CAX8R CAX8RH CAX8T "
        "CAX8RT CPEG8 CPEG8H CPEG8R CPEG8RH DC2D8 DCAX8"
    ),
    "tetra": "C3D4 C3D4H C3D4T DC3D4",
    "pyramid": "C3D5 C3D5H",
    "wedge": "C3D6 C3D6H C3D6T DC3D6",
    "hexahedron": "C3D8 C3D8H C3D8I C3D8IH C3D8R C3D8RH C3D8S C3D8T C3D8HT C3D8RT C3D8RHT DC3D8",
    "tetra10": "C3D10 C3D10H C3D10I C3D10M C3D10MH C3D10T C3D10MT C3D10HS DC3D10",
    "wedge15": "C3D15 C3D15H C3D15T DC3D15",
    "hexahedron20": "C3D20 C3D20H C3D20R C3D20RH C3D20T C3D20RT C3D20HT C3D20RHT DC3D20",
    "hexahedron27": "C3D27 C3D27H C3D27R C3D27RH",
}


def extend() -> None:
    """meshio's Abaqus table given the types of _MORE it lacks (its own entries kept)."""
    from meshio.abaqus import _abaqus

    table = _abaqus.abaqus_to_meshio_type
    for cell, names in _MORE.items():
        for name in names.split():
            table.setdefault(name, cell)
