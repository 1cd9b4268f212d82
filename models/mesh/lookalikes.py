"""Files that ParaView opens by an extension of ours with another reader: an XYZ list of atoms
(.xyz, ParaView's XYZ molecule reader; ours is PLOT3D's) and a Movie.BYU surface (.g, ParaView's
BYU reader; ours is Exodus II's). Each test looks at the file's first lines only, so that the
refusal can say what the file looks like rather than what the format tried found wrong in it."""

from __future__ import annotations

import re

# an XYZ molecule: a line with the atom count, a comment line, then "symbol x y z" rows
_NUMBER = rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][-+]?\d+)?"
_ATOM = re.compile(rb"^\s*[A-Za-z][A-Za-z0-9_+-]{0,15}\s+" + rb"\s+".join([_NUMBER] * 3) + rb"(?:\s.*)?$")
_COUNT = re.compile(rb"^\s*\d+\s*$")
# Movie.BYU's first line: parts, points, polygons, connectivity entries (vtkBYUWriter, ParaView)
_BYU_HEAD = re.compile(rb"^\s*\d+\s+\d+\s+\d+\s+\d+\s*\r?\n\s*\d+\s+\d+\s*\r?\n")


def xyz_molecule(head: bytes) -> str | None:
    """What to say of a .xyz file that is an XYZ list of atoms (a count line, a comment line, then
    rows of an element symbol or name and three coordinates), or None where it is not one."""
    lines = head.split(b"\n")
    if len(lines) < 3 or not _COUNT.match(lines[0]):
        return None
    atoms = int(lines[0])
    rows = [ln for ln in lines[2 : 2 + min(atoms, 20)] if ln.strip()]
    if atoms < 1 or not rows or not all(_ATOM.match(ln) for ln in rows):
        return None
    return (
        f"it is not a PLOT3D grid but looks like an XYZ list of {atoms:,} atom{'s' if atoms > 1 else ''} "
        "(a count line, a comment line, then rows of an element and its x y z, as ParaView's XYZ "
        "molecule reader reads them): points without cells; give a volume or planar mesh"
    )


def byu_surface(head: bytes) -> str:
    """What to add to the refusal of a .g file that is neither netCDF nor HDF5 (not Exodus II)."""
    looks = (
        "it looks like a Movie.BYU surface (4 counts on its first line, a part's range on its second"
        if _BYU_HEAD.match(head)
        else "a .g file that is not Exodus II may be a Movie.BYU surface ("
    )
    return (
        f"{looks}{'; ' if looks.endswith('second') else ''}ParaView reads .g files as Movie.BYU too), "
        "a surface format not read here: give the volume or planar mesh, or save this surface from "
        "ParaView as .stl or .vtu (a planar surface is then read as a 2D mesh)"
    )
